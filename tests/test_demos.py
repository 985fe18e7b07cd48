"""Every demo runs in quick mode, in serial and under mpirun, with the same numbers."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from conftest import ROOT, run_mpi


def _run(demo: str, nprocs: int, out) -> dict:
    run_mpi(nprocs, [f"demos/{demo}", "--quick", "--out", str(out)], timeout=600)
    return json.loads((out / "summary.json").read_text())


def _same(a, b, rtol: float) -> None:
    """Nested JSON values equal, numbers to a relative tolerance."""
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _same(a[k], b[k], rtol)
    elif isinstance(a, list):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            _same(x, y, rtol)
    elif isinstance(a, float):  # abs: a floor for values at rounding level (near 0)
        assert a == pytest.approx(b, rel=rtol, abs=1e-14)
    else:
        assert a == b


SUMMARY_KEYS = {"parameters", "reference", "versions", "mpi_size"}


def _same_run(serial: dict, parallel: dict, rtol: float) -> None:
    """Serial and 2-rank summaries agree (all but ``mpi_size``)."""
    assert (serial.pop("mpi_size"), parallel.pop("mpi_size")) == (1, 2)
    _same(serial, parallel, rtol)


def test_quality_demo(tmp_path):
    serial = _run("quality.py", 1, tmp_path / "s")
    assert {"circle", "spline"} | SUMMARY_KEYS == serial.keys()
    assert serial["parameters"]["quick"] is True
    assert serial["parameters"]["R_r_over_h"] == pytest.approx(3.0)
    assert serial["parameters"]["alpha"] == pytest.approx(0.75)
    assert serial["reference"]["Q2_max"] == pytest.approx(2 * 13**0.5 / 3)
    keys = {
        "h_over_R",
        "eta",
        "relax",
        "n_cells",
        "n_positively_cut",
        "theta_min_deg",
        "theta_max_deg",
        "q_max",
        "Q3_max",
        "Q2_max",
        "Q1_max",
    }
    assert all(set(r) == keys for r in serial["circle"])
    keys = {
        "level",
        "eta",
        "relax",
        "n_cells",
        "n_positively_cut",
        "percent_unaltered",
        "theta_min_deg",
        "theta_max_deg",
        "q_max",
    }
    assert all(set(r) == keys for r in serial["spline"])
    # Every study before and after the relaxation; the relaxed circles meet the targets.
    for rows in (serial["circle"], serial["spline"]):
        assert sorted({r["relax"] for r in rows}) == [False, True]
    assert serial["parameters"]["relax"] == [False, True]
    for r in serial["circle"]:
        if r["relax"]:
            assert r["theta_min_deg"] >= 40.0 and r["theta_max_deg"] <= 95.0 and r["q_max"] <= 2.6
    for name in ("circle_meshes.png", "circle_quality.png", "spline_meshes.png"):
        assert (tmp_path / "s" / name).stat().st_size > 10_000
    # The same meshes on 1 and 2 ranks: positions may differ by rounding (~1e-15), which
    # moves angles and ratios by about 1e-15 / h ~ 1e-13; a changed mesh moves them >= 1e-9.
    _same_run(serial, _run("quality.py", 2, tmp_path / "p"), rtol=1e-10)


def test_poisson_demo(tmp_path):
    serial = _run("poisson_convergence.py", 1, tmp_path / "s")
    assert {"rows", "rates"} | SUMMARY_KEYS == serial.keys()
    assert serial["parameters"]["degrees"] == [1, 2, 3, 4]
    assert serial["reference"]["optimal_rates"][0] == {"k": 1, "L2": 2, "H1": 1}
    rows = serial["rows"]
    assert {r["map"] for r in rows} == {"I", "I~", "G"} and {r["k"] for r in rows} == {1, 2, 3, 4}
    assert set(rows[0]) == {
        "map", "k", "geometry_degree", "h", "n_cells", "L2", "H1", "L2_roundoff", "H1_roundoff"
    }  # fmt: skip
    assert set(serial["rates"][0]) == {
        "map", "k", "L2_rate", "H1_rate", "L2_fit", "H1_fit", "L2_levels", "H1_levels"
    }  # fmt: skip
    # The quick levels' errors (1e-9 and more) are far above the round-off floor (the
    # estimates are 1e-13 and less), so the rates are taken between the two finest levels.
    for r in rows:
        assert r["L2"] > 1e3 * r["L2_roundoff"] and r["H1"] > 1e3 * r["H1_roundoff"], r
    for r in serial["rates"]:
        assert r["L2_levels"] == r["H1_levels"] == [1, 2], r
    # Even on the quick (coarse) levels the rates are about optimal.
    for r in serial["rates"]:
        assert r["L2_rate"] > r["k"] + 1 - 0.3 and r["H1_rate"] > r["k"] - 0.3, r
    for name in ("convergence_L2.png", "convergence_H1.png", "closeup_k2.png", "closeup_k3.png"):
        assert (tmp_path / "s" / name).stat().st_size > 10_000
    parallel = _run("poisson_convergence.py", 2, tmp_path / "p")
    assert parallel["parameters"] == serial["parameters"] and parallel["mpi_size"] == 2
    # Same meshes, same discrete problems: errors agree to solver rounding. The smallest
    # quick error, 1e-9 (k = 4), has round-off estimates near 1e-14, so 1e-5 relative
    # leaves room for the rounding of any factorisation (measured: 1e-9 relative).
    for a, b in zip(rows, parallel["rows"]):
        assert a["n_cells"] == b["n_cells"]
        assert np.isclose(a["L2"], b["L2"], rtol=1e-5) and np.isclose(a["H1"], b["H1"], rtol=1e-5)


def test_poisson_rates_above_the_round_off_floor():
    """The rates are taken between the finest levels whose errors exceed TRUSTED times
    their round-off estimates: an error at the floor (the last one, 10 times its estimate,
    as k = 4 at its finest level) is left out, and a series without such a pair has no
    rate, which the check rejects."""
    sys.path.insert(0, str(ROOT / "demos"))
    try:
        import poisson_convergence as demo
    finally:
        sys.path.pop(0)
    h = 0.3125 / 2.0 ** np.arange(5)
    err = np.array([1.7e-6, 5.7e-8, 1.5e-9, 3.2e-11, 7.7e-13])
    roundoff = np.array([1e-16, 2e-16, 5e-15, 2e-14, 7e-14])
    assert demo.finest_trusted(err, roundoff) == 3
    assert demo.finest_trusted(err[:2], np.full(2, 1e-10)) is None
    rows = [
        {"map": m, "k": 4, "h": h[i], "L2": err[i], "H1": 100 * err[i],
         "L2_roundoff": roundoff[i], "H1_roundoff": roundoff[i]}
        for m in demo.MAPS for i in range(5)
    ]  # fmt: skip
    rates = demo.convergence_rates(demo.MPI.COMM_SELF, rows, [4])
    expected = np.log2(err[2] / err[3])
    for r in rates:
        assert r["L2_levels"] == [2, 3] and r["L2_rate"] == pytest.approx(expected), r
        assert r["H1_levels"] == [3, 4], r  # 100 times the error: above the floor there
    for r in rows[-5:]:  # the last map: every level at the floor
        r["L2"] = r["L2_roundoff"]
    rates = demo.convergence_rates(demo.MPI.COMM_SELF, rows, [4])
    assert rates[-1]["L2_rate"] is None
    with pytest.raises(AssertionError):
        demo.check(rows, rates, [4], quick=False)


def _without_seconds(value):
    """A summary without its wall-clock times (they differ from run to run)."""
    if isinstance(value, dict):
        return {k: _without_seconds(v) for k, v in value.items() if not k.startswith("seconds")}
    if isinstance(value, list):
        return [_without_seconds(v) for v in value]
    return value


def test_quality_3d_demo(tmp_path):
    serial = _run("quality_3d.py", 1, tmp_path / "s")
    assert {"rows", "table", "histograms", "mesh_domain"} | SUMMARY_KEYS == serial.keys()
    assert serial["parameters"]["quick"] is True
    assert serial["reference"]["targets_deg"] == [30.0, 125.0]
    rows, table = serial["rows"], serial["table"]
    assert set(rows[0]) == {
        "shape",
        "lattice",
        "h_over_R",
        "n_cells",
        "n_positively_cut",
        "n_inverted",
        "theta_min_deg",
        "theta_max_deg",
        "radius_ratio_min",
        "mean_ratio_min",
        "volume_error_over_h2",
        "seconds",
    }
    assert set(rows[0]["seconds"]) == {
        "classify",
        "project",
        "relax",
        "map",
        "mesh",
        "conform",
        "background",
    }
    # 3 shapes x 2 sizes x 2 lattices, 2 placements each
    assert len(table) == 12 and len(rows) == 24 and all(t["placements"] == 2 for t in table)
    assert {t["lattice"] for t in table} == {"A15", "BCC"}
    assert {t["shape"] for t in table} == {"sphere", "ellipsoid", "torus"}
    assert {t["h_over_R"] for t in table} == {0.25, 0.125}
    for t in table:
        assert t["theta_min_worst"] <= t["theta_min_median"] <= t["theta_max_median"]
        assert t["theta_max_median"] <= t["theta_max_worst"]
        assert 0 < t["volume_error_over_h2_median"] <= t["volume_error_over_h2_worst"] < 1
        if t["lattice"] == "A15":
            assert t["within_targets"] and 30 <= t["theta_min_worst"], t
    for r in rows:
        assert r["n_inverted"] == 0 and 0 < r["mean_ratio_min"] <= 1
    cells = {lat: {} for lat in ("A15", "BCC")}
    for r in rows:
        n = str(round(1 / r["h_over_R"]))
        cells[r["lattice"]][n] = cells[r["lattice"]].get(n, 0) + r["n_cells"]
    for lattice, by_h in serial["histograms"].items():
        for n, counts in by_h.items():
            assert len(counts) == 180 and sum(counts) == 6 * cells[lattice][n]
    for name in ("meshes.png", "dihedral_histogram.png"):
        assert (tmp_path / "s" / name).stat().st_size > 10_000
    # Through mesh_domain: 3 shapes x 2 set-ups x 2 sizes and auto in the large box at R/4,
    # 1 placement each, at the size asked for; the auto set-up takes A15 in its small box,
    # the graded one grades, auto in the large box grades or (one round) takes A15 where
    # the octree leaves [30, 125].
    md = serial["mesh_domain"]
    assert len(md["table"]) == 15 and len(md["rows"]) == 15
    for r in md["rows"]:
        assert r["h_min"] == pytest.approx(r["h_over_R"]), r
        octree = r["background"] == "graded BCC octree"
        if r["setup"] == "auto3x":  # A15 chosen at once, or after the octree's angles
            assert r["refinement_rounds"] == (0 if octree else len(r["refinements"])), r
            assert all("auto keeps it within" in note for note in r["refinements"]), r
        else:
            assert r["refinement_rounds"] == 0, r
            assert octree == (r["setup"] == "graded"), r
        assert (r["n_background_half_pyramids"] > 0) == octree, r
        assert 20 < r["theta_min_deg"] and r["theta_max_deg"] < 130, r
        if r["setup"] != "graded":
            assert 30 <= r["theta_min_deg"] and r["theta_max_deg"] <= 125, r
        assert 0 < abs(r["volume_error_over_h2"]) < 1, r
    # The same meshes on 2 and 3 ranks are the -m mpi tests' (test_conform_3d,
    # test_graded_tet, test_property_surfaces: lattices, octrees, mesh_domain); this demo's
    # 2-rank run repeated them at a minute of the suite's 10.


def test_poisson_3d_demo(tmp_path):
    serial = _run("poisson_3d.py", 1, tmp_path / "s")
    assert {"rows", "rates", "seconds"} | SUMMARY_KEYS == serial.keys()
    assert serial["parameters"]["quick"] is True
    assert serial["parameters"]["h"] == {k: [0.4, 0.2] for k in ("1", "2", "3")}
    assert serial["reference"]["optimal_rates"][0] == {"k": 1, "L2": 2, "H1": 1}
    rows, rates = serial["rows"], serial["rates"]
    assert set(rows[0]) == {
        "surface",
        "k",
        "q",
        "h",
        "n_cells",
        "dofs",
        "boundary_dof_distance",
        "L2",
        "H1",
        "solver",
        "iterations",
        "seconds",
    }
    assert set(rows[0]["seconds"]) == {"mesh", "solve", "errors"}
    cases = {(1, 1), (2, 2), (3, 3), (2, 1)}
    assert len(rows) == 3 * 2 * len(cases)
    assert {(r["k"], r["q"]) for r in rows} == cases
    assert {r["surface"] for r in rows} == {"ball", "ellipsoid", "torus"}
    for r in rows:  # the boundary dofs of the curved meshes lie on the surface
        assert (r["boundary_dof_distance"] < 1e-12) == (r["q"] == r["k"]), r
    # Even on the two quick sizes the curved rates are about optimal, and the straight P2
    # has lost its order (L2 about 2, H1 about 1.5).
    for r in rates:
        k = r["k"]
        if r["q"] == k:
            assert r["L2_rate"] > k + 1 - 0.3 and r["H1_rate"] > k - 0.2, r
        else:
            assert r["L2_rate"] < k + 0.2 and r["H1_rate"] < k - 0.3, r
    for name in ("convergence.png", "ball_mesh.png"):
        assert (tmp_path / "s" / name).stat().st_size > 10_000
    # The same meshes on 2 ranks, the same discrete problems (MUMPS): the same errors up
    # to the solver's rounding; times differ and are left out.
    parallel = _run("poisson_3d.py", 2, tmp_path / "p")
    _same_run(_without_seconds(serial), _without_seconds(parallel), rtol=1e-9)
