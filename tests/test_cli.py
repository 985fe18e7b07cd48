"""Command line: shapes (curves and surfaces), output files, summary, argument and meshing
errors, MPI."""

from __future__ import annotations

import json
from pathlib import Path

from mpi4py import MPI

import numpy as np
import pytest
from conftest import needs_ranks
from dolfinx import io

from dolfinx_universal import ImplicitSurface
from dolfinx_universal.cli import (
    ArgumentError,
    build_parser,
    grid_topology,
    implicit_functions,
    main,
    polar_functions,
    run,
)

comm = MPI.COMM_WORLD
ROOT = Path(__file__).resolve().parents[1]


def spline_points(n: int = 14) -> np.ndarray:
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    r = 1.0 + 0.25 * np.sin(2 * t)
    return np.column_stack([r * np.cos(t), r * np.sin(t)])


def write_points(path: Path, fmt: str) -> Path:
    if comm.rank == 0:
        p = spline_points()
        if fmt == "csv":
            np.savetxt(path, p, delimiter=",", header="x,y", comments="")
        else:
            path.write_text(json.dumps({"points": p.tolist()}))
    comm.barrier()
    return path


def read_summary(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())


def check_summary(s: dict, shape: str) -> None:
    q = s["quality"]
    assert s["shape"]["type"] == shape
    assert s["n_cells"] == q["n_cells"] > 0
    assert 0 < q["n_positively_cut"] < s["n_cells"]
    assert q["n_inverted"] == 0 and q["min_area_ratio"] > 0
    assert 0 < q["theta_min_deg"] <= 60 <= q["theta_max_deg"] < 180
    assert s["facets"]["counts"]["immersed"] >= 3 and s["facets"]["counts"]["outer"] == 0
    assert s["n_background_cells"] > s["n_cells"]
    assert s["alpha"] == pytest.approx(0.75) and s["R_r"] == pytest.approx(3 * s["h"])
    assert s["timings_s"]["total"] > 0


@pytest.mark.parametrize(
    "shape, args",
    [
        ("circle", ["--circle", "1.0", "--center", "0.3", "-0.2"]),
        ("ellipse", ["--ellipse", "1.5", "0.8", "--angle", "30", "--no-plot"]),
        ("polar", ["--polar", "1 + 0.2*cos(3*theta)", "--no-plot"]),
        ("spline", ["--spline", "points.csv", "--no-plot"]),
        ("spline", ["--spline", "points.json", "--h", "0.12", "--no-plot"]),
    ],
)
def test_shapes(mpi_tmp_path, capsys, shape, args):
    out = mpi_tmp_path / "out"
    args = [
        str(write_points(mpi_tmp_path / a, a[-4:].lstrip("."))) if a.startswith("points") else a
        for a in args
    ]
    assert main([*args, "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    if comm.rank == 0:
        assert "cells" in captured.out
    names = ["mesh.xdmf", "mesh.h5", "summary.json"]
    if "--no-plot" not in args:
        names.append("mesh.png")
    for name in names:
        assert (out / name).is_file() and (out / name).stat().st_size > 0
    assert (out / "mesh.bp").is_dir()
    s = read_summary(out)
    check_summary(s, shape)
    if "--h" in args:
        assert s["h"] == 0.12


def test_curved_outputs(mpi_tmp_path):
    out2, out3 = mpi_tmp_path / "p2", mpi_tmp_path / "p3"
    assert main(["--circle", "1", "--degree", "2", "--out", str(out2), "--quiet"]) == 0
    s = read_summary(out2)
    check_summary(s, "circle")
    assert s["degree"] == 2 and s["map"] == "I" and 0 < s["curved"]["min_jacobian_ratio"] <= 1
    with io.XDMFFile(comm, out2 / "mesh.xdmf", "r") as xdmf:  # mesh and tags read back
        msh = xdmf.read_mesh(name="mesh")
        msh.topology.create_connectivity(1, 2)
        tags = xdmf.read_meshtags(msh, name="facet_tags")
    assert msh.topology.index_map(2).size_global == s["n_cells"]
    assert msh.geometry.cmaps[0].degree == 2
    owned = tags.find(1) < msh.topology.index_map(1).size_local
    assert comm.allreduce(int(owned.sum())) == s["facets"]["counts"]["immersed"]

    # Any degree: the checkpoint is read back with its tags.
    out4 = mpi_tmp_path / "p4"
    assert main(["--circle", "1", "--degree", "4", "--out", str(out4), "--quiet", "--no-plot"]) == 0
    from dolfinx_universal.io import read_mesh

    m4, t4 = read_mesh(comm, out4 / "mesh.vtkhdf")
    s4 = read_summary(out4)
    assert (
        m4.geometry.cmaps[0].degree == 4 and m4.topology.index_map(2).size_global == s4["n_cells"]
    )
    nf = m4.topology.index_map(1).size_local
    assert comm.allreduce(int((t4.find(1) < nf).sum())) == s4["facets"]["counts"]["immersed"]

    argv = ["--circle", "1", "--degree", "3", "--map", "G~", "--no-plot", "--quiet"]
    assert main([*argv, "--out", str(out3)]) == 0
    s3 = read_summary(out3)
    assert s3["n_cells"] == s["n_cells"] and s3["map"] == "G~"
    assert not (out3 / "mesh.xdmf").exists() and not (out3 / "mesh.png").exists()
    assert (out3 / "mesh.bp").is_dir()


def test_help(capsys):
    assert main(["--help"]) == 0
    text = capsys.readouterr().out
    if comm.rank == 0:
        for option in (
            "--circle",
            "--ellipse",
            "--polar",
            "--spline",
            "--h",
            "--margin",
            "--eta",
            "--rr",
            "--alpha",
            "--degree",
            "--map",
            "--out",
        ):
            assert option in text
        assert "default: 0.2" in text


@pytest.mark.parametrize(
    "args, fragment",
    [
        ([], "one of the arguments"),
        (["--circle", "1", "--ellipse", "1", "2"], "not allowed"),
        (["--circle", "1", "--h", "-0.1"], "--h must be a positive"),
        (["--circle", "0"], "--circle R must be a positive"),
        (["--ellipse", "1", "-2"], "--ellipse B"),
        (["--circle", "1", "--rr", "0.5"], "--rr must exceed 1"),
        (["--circle", "1", "--alpha", "0.5"], "--alpha must lie in"),
        (["--circle", "1", "--map", "X"], "invalid choice"),
        (["--circle", "1", "--h", "abc"], "invalid float value"),
        (["--spline", "does-not-exist.csv"], "no such file"),
        (["--polar", "1 + sin(theta"], "invalid polar expression"),
        (["--polar", "__import__('os')"], "unknown name '__import__'"),
        (["--polar", "np.__dict__"], "only np.<function> attributes"),
        (["--polar", "1 + nope(theta)"], "unknown name 'nope'"),
        (["--polar", "0.5 + cos(theta)"], "must be positive"),
        (["--polar", "1 + 0.1*theta"], "not 2*pi-periodic"),
    ],
)
def test_bad_arguments(mpi_tmp_path, capsys, args, fragment):
    assert main([*args, "--out", str(mpi_tmp_path / "bad"), "--no-plot"]) == 2
    err = capsys.readouterr().err
    if comm.rank == 0:
        assert err.startswith("dolfinx-universal: error: ") and err.count("\n") == 1
        assert fragment in err
    else:
        assert err == ""
    assert not (mpi_tmp_path / "bad" / "summary.json").exists()


def test_bad_spline_file(mpi_tmp_path, capsys):
    path = mpi_tmp_path / "bad.csv"
    if comm.rank == 0:
        path.write_text("x,y\n0,0\n1,0\nnot numbers\n")
    comm.barrier()
    assert main(["--spline", str(path), "--out", str(mpi_tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    if comm.rank == 0:
        assert err.startswith("dolfinx-universal: error: --spline") and err.count("\n") == 1


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--circle", "0.4", "--h", "0.5", "--uniform"], "inverted"),  # h too coarse
        (["--circle", "0.1", "--h", "0.5", "--uniform"], "no background vertex lies inside"),
    ],
)
def test_meshing_failure(mpi_tmp_path, capsys, args, fragment):
    assert main([*args, "--out", str(mpi_tmp_path / "fail")]) == 1
    err = capsys.readouterr().err
    if comm.rank == 0:
        assert err.startswith("dolfinx-universal: error: ") and err.count("\n") == 1
        assert fragment in err
    assert not (mpi_tmp_path / "fail" / "summary.json").exists()


@pytest.mark.parametrize(
    "args",
    [
        ["--circle", "0.4", "--h", "0.5"],  # the cases --uniform refuses
        ["--circle", "0.1", "--h", "0.5"],
        ["--polar", "1 + 0.3*cos(5*theta)", "--degree", "2"],
        ["--polar", "1 + 0.3*cos(5*theta)", "--degree", "2", "--h", "0.05"],
        ["--spline", "star.csv", "--degree", "2"],
        ["--spline", "star.csv", "--degree", "4"],
    ],
)
def test_graded_by_default(mpi_tmp_path, args):
    """The shapes a new user tries mesh with the defaults; the summary has the certificate."""
    star = mpi_tmp_path / "star.csv"
    if comm.rank == 0:
        t = np.linspace(0, 2 * np.pi, 10, endpoint=False)
        r = np.where(np.arange(10) % 2 == 0, 1.0, 0.5)
        np.savetxt(star, np.column_stack([r * np.cos(t), r * np.sin(t)]), delimiter=",")
    comm.barrier()
    args = [str(star) if a == "star.csv" else a for a in args]
    out = mpi_tmp_path / "graded"
    assert main([*args, "--out", str(out), "--no-plot", "--quiet"]) == 0
    s = read_summary(out)
    cert = s["certificate"]
    assert s["background"] == "graded (mesh_domain)" and s["quality"]["n_inverted"] == 0
    assert cert["num_loops"] == 1 and cert["num_pieces"] == 1
    assert cert["max_conditioning_angle_deg"] < 90 and cert["min_jacobian_ratio"] > 0
    assert cert["min_angle_deg"] >= cert["min_angle_floor_deg"] == 10
    assert "certificate" in s["certificate_text"]


def test_polar_derivatives():
    theta = np.linspace(-np.pi, 3 * np.pi, 101)
    r, dr, d2r, method = polar_functions("1 + 0.2*cos(3*theta)")
    assert method == "complex-step"
    # r: the same numpy expression (an ulp at most); r': the complex step, the complex cos of
    # libm against numpy's real sin (a few ulps of 0.6; 1e-14 = 90 ulps)
    np.testing.assert_allclose(r(theta), 1 + 0.2 * np.cos(3 * theta), rtol=1e-15)
    np.testing.assert_allclose(dr(theta), -0.6 * np.sin(3 * theta), atol=1e-14)
    np.testing.assert_allclose(d2r(theta), -1.8 * np.cos(3 * theta), atol=1e-10)
    # Not complex-safe (np.abs): fourth-order finite differences.
    r, dr, d2r, method = polar_functions("1.5 + 0.1*np.abs(sin(theta))**3")
    assert method == "finite-difference"
    t = np.linspace(0.3, 2.8, 11)  # where sin > 0
    np.testing.assert_allclose(dr(t), 0.3 * np.sin(t) ** 2 * np.cos(t), atol=1e-10)
    np.testing.assert_allclose(
        d2r(t), 0.6 * np.sin(t) * np.cos(t) ** 2 - 0.3 * np.sin(t) ** 3, atol=1e-7
    )
    r, dr, d2r, _ = polar_functions("2")  # constants broadcast
    assert r(theta).shape == theta.shape and np.all(dr(theta) == 0) and np.all(d2r(theta) == 0)
    with pytest.raises(ArgumentError):
        polar_functions("log(cos(theta))")  # NaN where cos < 0


@pytest.mark.mpi
@needs_ranks(2)
def test_mpirun_matches_serial(mpi_tmp_path, capsys):
    args = ["--circle", "1.0", "--center", "0.05", "0.02", "--h", "0.3"]
    assert main([*args, "--out", str(mpi_tmp_path / "mpi")]) == 0
    printed = capsys.readouterr().out
    assert printed.count("unaltered") == (1 if comm.rank == 0 else 0)  # rank 0 prints alone
    assert printed.count("universal mesh certificate") == (1 if comm.rank == 0 else 0)
    own = mpi_tmp_path / f"serial{comm.rank}"
    serial = run(build_parser().parse_args([*args, "--out", str(own), "--no-plot"]), MPI.COMM_SELF)
    parallel = read_summary(mpi_tmp_path / "mpi")
    assert parallel["mpi_size"] == comm.size
    assert parallel["n_cells"] == serial["n_cells"]
    assert parallel["facets"] == serial["facets"]
    for key in ("n_positively_cut", "n_unaltered", "n_inverted"):
        assert parallel["quality"][key] == serial["quality"][key]
    # the same mesh: angles agree to rounding (default rel 1e-6: far above it)
    assert parallel["quality"]["theta_min_deg"] == pytest.approx(serial["quality"]["theta_min_deg"])
    assert parallel["certificate"]["num_cells"] == serial["certificate"]["num_cells"]
    assert (mpi_tmp_path / "mpi" / "mesh.png").stat().st_size > 0


@pytest.mark.mpi
def test_unwritable_out_fails_on_every_rank(mpi_tmp_path, capsys):
    """Rank 0 cannot create --out (a file is in the way): every rank returns 2, none hangs."""
    blocker = mpi_tmp_path / "a_file"
    if comm.rank == 0:
        blocker.write_text("x")
    comm.barrier()
    assert main(["--circle", "1", "--out", str(blocker / "sub"), "--no-plot"]) == 2
    err = capsys.readouterr().err
    if comm.rank == 0:
        assert "cannot create the output folder" in err and err.count("\n") == 1


def test_far_from_origin_and_version(mpi_tmp_path, capsys):
    assert main(["--circle", "1", "--center", "1e17", "0", "--out", str(mpi_tmp_path)]) == 2
    err = capsys.readouterr().err
    if comm.rank == 0:
        assert "move it near the origin" in err and err.count("\n") == 1
    with pytest.raises(SystemExit) as info:
        build_parser().parse_args(["--version"])
    assert info.value.code == 0
    if comm.rank == 0:
        out = capsys.readouterr().out
        assert "dolfinx-universal 0." in out and "DOLFINx 0.11" in out


@pytest.mark.skip_in_parallel
def test_without_matplotlib(tmp_path, capsys, monkeypatch):
    """No matplotlib: a warning, no mesh.png, and still a summary."""
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a: None if name == "matplotlib" else real(name, *a),
    )
    assert main(["--circle", "1", "--out", str(tmp_path)]) == 0
    assert "matplotlib is not installed" in capsys.readouterr().err
    assert (tmp_path / "summary.json").exists() and not (tmp_path / "mesh.png").exists()


# ------------------------------------------------------------------------------- surfaces
TORUS_EXPR = "(sqrt(x**2 + y**2) - 1)**2 + z**2 - 0.3**2"


def check_surface_summary(s: dict, shape: str) -> None:
    q = s["quality"]
    assert s["dimension"] == 3 and s["degree"] == 1 and s["shape"]["type"] == shape
    assert s["n_cells"] == q["n_cells"] > 0 and q["n_inverted"] == 0
    assert 0 < q["n_positively_cut"] < s["n_cells"]
    assert q["min_volume_ratio"] > 0 and 0 < q["mean_ratio_min"] <= 1
    # the targets for the relaxed tetrahedra
    assert 30.0 <= q["theta_min_deg"] and q["theta_max_deg"] <= 125.0
    assert sum(q["dihedral_histogram"]) == 6 * q["n_cells"]
    assert s["facets"]["counts"]["immersed"] >= 4 and s["facets"]["counts"]["outer"] == 0
    assert s["n_background_cells"] > s["n_cells"]
    assert s["timings_s"]["total"] > 0 and s["timings_s"]["conform.relax"] > 0


@pytest.mark.mpi
@pytest.mark.parametrize(
    "shape, args",
    [
        ("sphere", ["--sphere", "1", "--h", "0.5"]),
        ("ellipsoid", ["--ellipsoid", "1", "0.9", "0.8", "--center", "0.1", "0", "-0.05"]),
        ("torus", ["--torus", "1", "0.4", "--uniform", "--h", "0.25", "--axis", "1", "0", "1"]),
        # R - r > R_r: the lattice vertices on the axis (a circle of closest points each)
        # stay out of the band
        ("implicit", ["--implicit", TORUS_EXPR, "--uniform", "--h", "0.2"]),
    ],
)
def test_surfaces(mpi_tmp_path, capsys, shape, args):
    """Each surface option meshes, writes its files and reads back with its face tags."""
    from dolfinx_universal.io import read_mesh

    out = mpi_tmp_path / shape
    plot = shape == "sphere"
    assert main([*args, "--out", str(out), *([] if plot else ["--no-plot"])]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    if comm.rank == 0:
        assert "tetrahedra" in captured.out and "dihedral angles in" in captured.out
    else:
        assert captured.out == ""
    s = read_summary(out)
    check_surface_summary(s, shape)
    names = ["mesh.vtkhdf", "mesh.tags.npz", "mesh.xdmf", "mesh.h5", "summary.json"]
    assert s["files"] == names[:2] + ["mesh.bp"] + names[2:4] + (["mesh.png"] if plot else []) + [
        "summary.json"
    ]
    for name in names + (["mesh.png"] if plot else []):
        assert (out / name).is_file() and (out / name).stat().st_size > 0
    if plot and comm.rank == 0:
        assert (out / "mesh.png").stat().st_size > 20_000
    uniform = "--uniform" in args
    assert (s["certificate"] is None) == uniform
    if uniform:
        assert s["background"] == "A15 uniform (--uniform)"
    else:  # the background mesh_domain chose, in the certificate and its 3D wording
        cert = s["certificate"]
        assert cert["background"] in ("A15 uniform", "graded BCC octree") and cert["tdim"] == 3
        assert s["background"] == f"{cert['background']} (mesh_domain)"
        text = s["certificate_text"]
        assert f"tetrahedra (degree 1) from the {cert['background']} background" in text
        assert "closed surface(s)" in text and "dihedral angles in" in text
        assert "triangle" not in text and "loop" not in text
        assert s["certificate"]["num_cells"] == s["n_cells"]
        assert s["h_used"] <= s["h"] and s["certificate"]["max_conditioning_angle_deg"] < 90
    if shape == "implicit":
        assert s["shape"]["genus"] == 1 and s["shape"]["num_components"] == 1
        assert s["shape"]["topology"] == "grid" and s["shape"]["gradient"] == "complex-step"
    if shape == "torus":
        assert s["shape"]["axis"] == pytest.approx([2**-0.5, 0, 2**-0.5])
    msh, tags = read_mesh(comm, out / "mesh.vtkhdf")
    assert msh.topology.index_map(3).size_global == s["n_cells"]
    nf = msh.topology.index_map(2).size_local
    assert comm.allreduce(int((tags.find(1) < nf).sum())) == s["facets"]["counts"]["immersed"]


@pytest.mark.mpi
def test_surface_background_is_the_one_used(mpi_tmp_path):
    """A small sphere in a wide box: mesh_domain takes the graded octree, and the summary
    says so (it said A15 whatever mesh_domain chose)."""
    out = mpi_tmp_path / "small"
    args = ["--sphere", "0.3", "--center", "0.0123", "0.0071", "0.0049", "--h", "0.8"]
    assert main([*args, "--margin", "1.7", "--no-plot", "--out", str(out)]) == 0
    s = read_summary(out)
    assert s["background"] == "graded BCC octree (mesh_domain)"
    assert s["certificate"]["background"] == "graded BCC octree"
    assert "from the graded BCC octree background" in s["certificate_text"]


def test_surface_help(capsys):
    assert main(["--help"]) == 0
    text = capsys.readouterr().out
    if comm.rank == 0:
        for option in (
            "--sphere",
            "--ellipsoid",
            "--torus",
            "--implicit",
            "--axis",
            "--box",
            "--genus",
            "--components",
        ):
            assert option in text


@pytest.mark.mpi
@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--sphere", "0"], "--sphere R must be a positive"),
        (["--sphere", "1", "--torus", "1", "0.5"], "not allowed"),
        (["--ellipsoid", "1", "-1", "1"], "--ellipsoid B must be a positive"),
        (["--ellipsoid", "1", "1"], "expected 3 arguments"),
        (["--torus", "1", "2"], "needs r < R"),
        (["--torus", "1", "0.3", "--axis", "0", "0", "0"], "--axis must be a finite non-zero"),
        (["--sphere", "1", "--degree", "0"], "--degree must be >= 1"),
        (["--sphere", "1", "--center", "0", "0"], "--center needs X Y Z for a surface"),
        (["--circle", "1", "--center", "0", "0", "0"], "--center needs X Y for a curve"),
        (["--sphere", "1", "--genus", "1"], "--genus applies to --implicit only"),
        (["--sphere", "1", "--box", "0", "0", "0", "1", "1", "1"], "--box applies to --implicit"),
        (["--circle", "1", "--axis", "0", "0", "1"], "--axis applies to --torus only"),
        (["--sphere", "1", "--angle", "30"], "--angle applies to --ellipse only"),
        (["--sphere", "1", "--h", "-0.1"], "--h must be a positive"),
        (["--sphere", "1", "--uniform", "--h", "0.001"], "background cells; use a larger h"),
        (["--sphere", "1", "--center", "1e17", "0", "0"], "move it near the origin"),
        (["--implicit", "x**2 + y**2 + z**2 + 1"], "found no solid (phi < 0)"),
        (["--implicit", "x**2 + nope"], "unknown name 'nope' (use x, y, z,"),
        (["--implicit", "__import__('os')"], "unknown name '__import__'"),
        (["--implicit", "x**2 + (y"], "invalid implicit expression"),
        (["--implicit", "1/(x - x)"], "is not finite"),
        (["--implicit", "x**2+y**2+z**2-1", "--box", "0", "0", "0", "1", "1", "1"], "leaves --box"),
        (["--implicit", "x**2+y**2+z**2-1", "--box", "0", "0", "0", "-1", "1", "1"], "X0 < X1"),
        (["--implicit", "x**2+y**2+z**2-1", "--genus", "-1"], "--genus must be >= 0"),
        (["--implicit", "x**2+y**2+z**2-1", "--components", "0"], "--components must be >= 1"),
        (  # a torus declared genus 0: the surface's grid counts genus 1, before any meshing
            ["--implicit", TORUS_EXPR, "--genus", "0", "--uniform", "--h", "0.3"],
            "counts 1 component(s) and genus 1, but genus = 0 given",
        ),
        (
            ["--implicit", TORUS_EXPR, "--components", "2"],
            "counts 1 component(s) and genus 1, but num_components = 2 given",
        ),
    ],
)
def test_bad_surface_arguments(mpi_tmp_path, capsys, args, fragment):
    """Every bad input: exit status 2 on every rank, one line on rank 0, no output files."""
    assert main([*args, "--out", str(mpi_tmp_path / "bad"), "--no-plot"]) == 2
    err = capsys.readouterr().err
    if comm.rank == 0:
        assert err.startswith("dolfinx-universal: error: ") and err.count("\n") == 1
        assert fragment in err, err
    else:
        assert err == ""
    assert not (mpi_tmp_path / "bad" / "summary.json").exists()


@pytest.mark.mpi
@pytest.mark.parametrize(
    "args, fragment",
    [
        (["--sphere", "0.05", "--uniform", "--h", "0.5"], "no background vertex lies inside"),
    ],
)
def test_surface_meshing_failure(mpi_tmp_path, capsys, args, fragment):
    assert main([*args, "--out", str(mpi_tmp_path / "fail"), "--no-plot"]) == 1
    err = capsys.readouterr().err
    if comm.rank == 0:
        assert err.startswith("dolfinx-universal: error: ") and err.count("\n") == 1
        assert fragment in err
    else:
        assert err == ""
    assert not (mpi_tmp_path / "fail" / "summary.json").exists()


def test_implicit_functions():
    """Gradient by complex step (or differences), a box around the surface, its topology."""
    p = np.random.default_rng(1).uniform(-1, 1, (50, 3))
    imp = implicit_functions("x**2 + 2*y**2 + 3*z**2 - 1", (0.1, 0.0, -0.2))
    assert imp.gradient == "complex-step"
    q = p - [0.1, 0.0, -0.2]
    np.testing.assert_allclose(imp.phi(p), (q**2 * [1, 2, 3]).sum(axis=1) - 1, rtol=1e-14)
    np.testing.assert_allclose(imp.grad(p), 2 * q * [1, 2, 3], rtol=1e-14, atol=1e-15)
    semi = np.array([1, 2**-0.5, 3**-0.5])
    lo, hi = imp.box
    assert np.all(lo < [0.1, 0, -0.2] - semi) and np.all(hi > [0.1, 0, -0.2] + semi)
    spacing = 2.0 * semi.max() / (64 - 1)  # the second grid's
    assert np.all(hi - ([0.1, 0, -0.2] + semi) < 4 * spacing)
    counted = ImplicitSurface(imp.phi, imp.grad, imp.box)  # the topology, as the CLI counts it
    assert (counted.num_components, counted.genus, counted.topology_counted) == (1, 0, True)
    # not complex-safe (np.abs): fourth-order differences
    imp = implicit_functions("np.abs(x)**3 + y**2 + z**2 - 1", (0, 0, 0))
    assert imp.gradient == "finite-difference"
    g = np.column_stack([3 * p[:, 0] * np.abs(p[:, 0]), 2 * p[:, 1], 2 * p[:, 2]])
    np.testing.assert_allclose(imp.grad(p), g, atol=1e-9)
    # a given box; a torus counted with genus 1
    imp = implicit_functions(TORUS_EXPR, (0, 0, 0), [[-2, -2, -1], [2, 2, 1]])
    assert imp.box.tolist() == [[-2, -2, -1], [2, 2, 1]]
    assert ImplicitSurface(imp.phi, imp.grad, imp.box).counted_topology == (1, 1)
    # a large solid far from the centre is found on the growing cubes
    imp = implicit_functions("(x - 30)**2 + y**2 + z**2 - 100", (0, 0, 0))
    assert imp.box[0, 0] < 20 < 40 < imp.box[1, 0]


@pytest.mark.parametrize(
    "phi, expected",
    [
        (lambda p: (p**2).sum(axis=1) - 1, (1, 0)),  # ball
        (lambda p: (np.hypot(p[:, 0], p[:, 1]) - 1) ** 2 + p[:, 2] ** 2 - 0.1, (1, 1)),  # torus
        (lambda p: np.maximum((p**2).sum(axis=1) - 1, 0.3 - (p**2).sum(axis=1)), (2, 0)),  # shell
        (  # two tori side by side
            lambda p: ((p[:, 0] ** 2 - 1) ** 2 + p[:, 1] ** 2 - 0.3) ** 2 + p[:, 2] ** 2 - 0.02,
            (2, 2),
        ),
    ],
)
def test_grid_topology(phi, expected):
    n = 64
    axes = [np.linspace(-1.7, 1.7, n)] * 3
    p = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    assert grid_topology((phi(p) < 0).reshape(n, n, n)) == expected
