"""mesh_domain and the command line with curved tetrahedra (degree 2 and 3): nodes on Gamma,
proven Jacobian ratios, the certificate, the refinement loop on an unproven cell, the same
mesh on 1 and 2 ranks, and ``--degree`` for surfaces."""

from __future__ import annotations

import json

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh

import dolfinx_universal as du
from dolfinx_universal.cli import main
from dolfinx_universal.io import read_mesh
from dolfinx_universal.meshing import domain as du_domain

comm = MPI.COMM_WORLD
C = np.array([0.0123, 0.0071, 0.0049])  # off the lattice's symmetry planes
# size_factor: coarser than the default (feature / 3) to keep the meshes small
CASES = {
    "sphere": (du.Sphere(C, 1.0), 2, None, 4.0 / 3.0 * np.pi),
    "ellipsoid": (du.Ellipsoid(C, (1.0, 0.7, 0.5)), 3, 1.5, 4.0 / 3.0 * np.pi * 0.35),
    "torus": (du.Torus(C, 1.0, 0.35), 2, 1.5, 2.0 * np.pi**2 * 0.35**2),
}


def _volume(msh: dmesh.Mesh) -> float:
    q = msh.geometry.cmaps[0].degree
    dx = ufl.dx(msh, metadata={"quadrature_degree": 3 * q})
    return msh.comm.allreduce(fem.assemble_scalar(fem.form(1.0 * dx)), op=MPI.SUM)


def _gamma_nodes(msh: dmesh.Mesh, tags: dmesh.MeshTags) -> np.ndarray:
    """Geometry nodes of the immersed faces (process-local)."""
    msh.topology.create_connectivity(2, 3)
    nodes = dmesh.entities_to_geometry(msh, 2, tags.find(du.IMMERSED))
    return msh.geometry.x[np.unique(nodes)]


@pytest.fixture(scope="module")
def meshed():
    cache: dict[str, du.MeshedDomain] = {}

    def get(name: str) -> du.MeshedDomain:
        if name not in cache:
            surface, degree, factor, _ = CASES[name]
            cache[name] = du.mesh_domain(comm, surface, 0.5, degree=degree, size_factor=factor)
        return cache[name]

    return get


@pytest.mark.parametrize("name", list(CASES))
def test_curved_mesh_domain(meshed, name):
    surface, degree, _, exact = CASES[name]
    md = meshed(name)
    c = md.certificate
    assert md.curved is not None and md.mesh is md.curved.mesh
    assert md.mesh.geometry.cmaps[0].degree == degree and md.mesh.topology.dim == 3
    # Certificate: the degree, the default map of tetrahedra, a proven positive ratio
    assert (c.degree, c.map, c.tdim) == (degree, "I~", 3)
    assert c.min_jacobian_ratio == md.curved.min_jacobian_ratio
    assert 0.5 < c.min_jacobian_ratio <= 1.0 + 1e-12  # measured 0.73-1.0
    assert c.num_cells == md.mesh.topology.index_map(3).size_global
    assert c.num_loops == 1 and c.num_pieces == 1
    assert f"(degree {degree}, map I~)" in str(c)
    assert json.loads(json.dumps(c.as_dict()))["min_jacobian_ratio"] == c.min_jacobian_ratio
    assert md.timings["curved"] > 0
    # Every node of an immersed face lies on Gamma
    x = _gamma_nodes(md.mesh, md.facet_tags)
    assert comm.allreduce(len(x)) > 0
    d = np.linalg.norm(surface.closest_point(x) - x, axis=1) if len(x) else np.zeros(1)
    assert comm.allreduce(float(d.max()), op=MPI.MAX) < 1e-13
    # The curved volume is far closer than the straight one (O(h^2))
    err = abs(_volume(md.mesh) / exact - 1)
    err_straight = abs(_volume(md.conforming.mesh) / exact - 1)
    assert err < err_straight / 10, (err, err_straight)


def test_map_argument(meshed):
    surface = CASES["sphere"][0]
    md = du.mesh_domain(comm, surface, 0.5, degree=2, map="I")
    ref = meshed("sphere")
    assert md.certificate.map == "I" and md.curved is not None and md.curved.map == "I"
    assert md.certificate.num_cells == ref.certificate.num_cells  # the same straight mesh
    # projecting the background's faces bends the cells more (measured 0.73 against 1.00)
    assert 0 < md.certificate.min_jacobian_ratio < ref.certificate.min_jacobian_ratio
    with pytest.raises(ValueError, match="unknown map"):
        du.mesh_domain(comm, surface, 0.5, degree=2, map="J")


def test_unproven_curved_cells_refine_the_background(monkeypatch):
    """A curved cell not proven valid is a refinable failure: the background is refined
    near it and the domain meshed again (the first curving refused here on purpose)."""
    real = du_domain.curved_mesh
    calls: list[int] = []

    def once(cm, degree, map):
        calls.append(cm.mesh.topology.index_map(3).size_global)
        if len(calls) == 1:
            raise du.MeshingError(
                "3 curved tetrahedra are not proven valid near (1, 0, 0)",
                np.array([[1.0, 0.0, 0.0]]),
            )
        return real(cm, degree, map)

    monkeypatch.setattr(du_domain, "curved_mesh", once)
    md = du.mesh_domain(comm, du.Sphere(C, 1.0), 0.5, degree=2, tet_background="a15")
    c = md.certificate
    assert len(calls) == 2 and calls[1] > calls[0]
    assert c.refinement_rounds == 1 and "not proven valid" in c.refinements[0]
    assert c.min_jacobian_ratio > 0 and c.h_min == pytest.approx(1.0 / 6.0)


def _quartic() -> du.ImplicitSurface:
    """The superellipsoid ``sum (x - C)^4 = 1``: flat and strongly curved parts, an implicit
    surface without its Hessian (closest points by Newton's method on differences)."""
    return du.ImplicitSurface(
        lambda x: ((x - C) ** 4).sum(axis=1) - 1.0,
        lambda x: 4.0 * (x - C) ** 3,
        [C - 1.1, C + 1.1],
        resolution=40,
    )


@pytest.mark.mpi
@pytest.mark.parametrize("name", ["torus", "quartic"])
def test_same_curved_mesh_on_any_number_of_ranks(name):
    """The same nodes to rounding (1e-13: the nodes are O(1); a node an ulp off before its
    projection used to move by up to 1e-10 on implicit surfaces, whose closest points
    stopped short of stationary: see ``test_surfaces``)."""
    surface, degree = (CASES["torus"][0], 2) if name == "torus" else (_quartic(), 3)
    md = du.mesh_domain(comm, surface, 0.5, degree=degree, size_factor=1.5)
    serial = du.mesh_domain(MPI.COMM_SELF, surface, 0.5, degree=degree, size_factor=1.5)
    a, b = md.certificate, serial.certificate
    assert a.num_cells == b.num_cells and a.refinement_rounds == b.refinement_rounds
    assert a.min_jacobian_ratio == pytest.approx(b.min_jacobian_ratio, abs=1e-12)
    assert _volume(md.mesh) == pytest.approx(_volume(serial.mesh), rel=1e-12)
    n = md.mesh.geometry.index_map().size_local
    assert comm.allreduce(n) == serial.mesh.geometry.index_map().size_local
    # the same nodes (order-free)
    x = np.concatenate(comm.allgather(md.mesh.geometry.x[:n]))
    key = np.lexsort(np.round(x, 9).T[::-1])
    y = serial.mesh.geometry.x[: len(x)]
    assert np.abs(x[key] - y[np.lexsort(np.round(y, 9).T[::-1])]).max() < 1e-13


@pytest.mark.mpi
def test_cli_degree_for_surfaces(mpi_tmp_path, capsys):
    out = mpi_tmp_path / "sphere2"
    argv = ["--sphere", "1", "--degree", "2", "--h", "0.5", "--out", str(out), "--no-plot"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    s = json.loads((out / "summary.json").read_text())
    assert s["dimension"] == 3 and s["degree"] == 2 and s["map"] == "I~"
    assert 0 < s["curved"]["min_jacobian_ratio"] == s["certificate"]["min_jacobian_ratio"]
    assert s["certificate"]["degree"] == 2 and "curved" in s["timings_s"]
    assert {"mesh.vtkhdf", "mesh.tags.npz", "mesh.xdmf"} <= set(s["files"])
    if comm.rank == 0:
        assert "(degree 2, map I~)" in text
    msh, tags = read_mesh(comm, out / "mesh.vtkhdf")
    assert msh.geometry.cmaps[0].degree == 2 and tags is not None
    assert msh.topology.index_map(3).size_global == s["n_cells"]
    assert msh.geometry.index_map().size_global == s["n_geometry_nodes"]
    x = _gamma_nodes(msh, tags)
    r = np.abs(np.linalg.norm(x, axis=1) - 1.0) if len(x) else np.zeros(1)
    assert comm.allreduce(float(r.max()), op=MPI.MAX) < 1e-13


def test_component_facets():
    """The immersed faces of a shell split by surface: the container's on the sphere of
    radius 1, the body's on the sphere of radius 0.5 (curved, degree 2), and together all
    of them; the areas of the two surfaces to O(h^4)."""
    outer, inner = du.Sphere([0.0, 0.0, 0.0], 1.0), du.Sphere([0.0, 0.0, 0.0], 0.5)
    md = du.mesh_domain(MPI.COMM_WORLD, du.Domain(outer, [inner]), 0.3, degree=2)
    container, body = md.component_facets()
    assert np.array_equal(
        np.sort(np.concatenate([container, body])), np.sort(md.facet_tags.find(du.IMMERSED))
    )
    tags = dmesh.meshtags(
        md.mesh,
        2,
        np.concatenate([container, body]),
        np.concatenate([np.full(len(container), 1), np.full(len(body), 2)]).astype(np.int32),
    )
    ds = ufl.Measure("ds", domain=md.mesh, subdomain_data=tags)
    comm = md.mesh.comm
    areas = [comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ds(k))), op=MPI.SUM) for k in (1, 2)]
    assert areas[0] == pytest.approx(4 * np.pi, rel=1e-3)
    assert areas[1] == pytest.approx(np.pi, rel=1e-3)
    (single,) = du.mesh_domain(MPI.COMM_WORLD, outer, 0.4).component_facets()
    assert len(single) > 0


def test_bad_box_and_tiny_h_get_clear_errors_at_once():
    """Found by an adversarial run: a 2D or non-finite box met numpy's reshape error or a
    "leaves the given box" error, and h = 1e-3 on a ball of radius 0.7 sampled its surface
    at h / 4 (1e8 points) for over 5 minutes (h = 1e-4: a 73 GiB allocation) before the
    cell count was checked. Every size is at most h, so the box around Gamma needs at least
    its volume / h^3 cells: refused before any sampling."""
    comm = MPI.COMM_WORLD
    ball = du.Sphere([0.0, 0.0, 0.0], 0.7)
    for box in ([[-1, -1], [1, 1]], [[np.nan] * 3, [1] * 3], [[1] * 3, [-1] * 3]):
        with pytest.raises(ValueError, match="box must be"):
            du.mesh_domain(comm, ball, 0.2, box=box)
    for kind in ("auto", "a15"):
        with pytest.raises(du.MeshingError, match=r"h = 0.001 asks for at least 2.74e\+09"):
            du.mesh_domain(comm, ball, 1e-3, tet_background=kind)


def _loose_ball(r: float = 0.5) -> du.ImplicitSurface:
    """A ball of radius ``r`` given as a level set in the loose box [-2, 2]^3: the default
    box (the surface's bounding box plus margins) holds 4.5e5 A15 tetrahedra of the target
    size r / 3, the box of its samples 4.6e4."""
    return du.ImplicitSurface(
        lambda x: (x**2).sum(axis=1) - r * r, lambda x: 2 * x, [[-2.0] * 3, [2.0] * 3], genus=0
    )


def test_auto_keeps_its_angles_in_the_box_of_gamma(monkeypatch):
    """``tet_background="auto"`` whose octree misses its dihedral angles
    (:data:`AUTO_DIHEDRAL`, here narrowed to (39.5, 110.5): the octree gives [38.9, 110.2])
    takes the A15 background where the default box's exceeds ``max_cells`` but that of
    Gamma's samples does not (an implicit surface in a loose box: the octree's angles were
    kept, down to 19 degrees on superellipsoids at degree 3)."""
    from dolfinx_universal.meshing import plans_tet

    monkeypatch.setattr(plans_tet, "AUTO_DIHEDRAL", (39.5, 110.5))
    md = du.mesh_domain(comm, _loose_ball(), 0.8, max_cells=2e5)
    c = md.certificate
    assert c.background == "A15 uniform" and c.refinement_rounds == 1
    assert "graded BCC octree (auto keeps it within (39.5, 110.5)), then the A15" in str(c)
    assert 39.5 <= c.min_angle_deg and c.max_angle_deg <= 110.5
    assert md.background.topology.index_map(3).size_global < 1e5  # the samples' box


def test_auto_refines_where_the_octree_misses_its_angles(monkeypatch):
    """Where no A15 background fits ``max_cells`` either, the octree is refined around the
    tetrahedra that miss the angles; the best mesh is kept where the next octree would
    exceed ``max_cells`` (the record says so)."""
    from dolfinx_universal.meshing import plans_tet

    monkeypatch.setattr(plans_tet, "AUTO_DIHEDRAL", (39.5, 110.5))
    md = du.mesh_domain(comm, _loose_ball(), 0.8, max_cells=4.5e4)
    c = md.certificate
    assert c.background == "graded BCC octree" and c.refinement_rounds == 1
    assert c.refinements[0].endswith(
        "refined there (the graded BCC octree would exceed max_cells; the octree's mesh kept)"
    )


def _superellipsoid(p: float, axes: tuple[float, float, float], half: float):
    """``|y/a|^p + |y/b|^p + |y/c|^p = 1`` for ``y = Q^T x`` (a fixed random rotation ``Q``),
    as an implicit surface in the box [-half, half]^3."""
    q = np.random.default_rng(0).normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    Q = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    a = np.asarray(axes)

    def phi(pts):
        return (np.abs(pts @ Q / a) ** p).sum(axis=1) - 1

    def grad(pts):
        t = pts @ Q / a
        return (p * np.abs(t) ** (p - 1) * np.sign(t) / a) @ Q.T

    return du.ImplicitSurface(phi, grad, [[-half] * 3, [half] * 3], genus=0)


@pytest.mark.parametrize(
    "p, axes", [(3.57, (0.60, 0.89, 0.36)), (3.82, (0.41, 0.86, 0.88))], ids=["p357", "p382"]
)
def test_auto_has_an_a15_fallback_at_degree_3(p, axes):
    """The superellipsoids on which ``auto`` at degree 3 (sizes feature / 4) kept the octree
    with dihedral angles down to 19 degrees: given in a loose box, the A15 background of the
    default box exceeds ``max_cells``, which kept the octree's mesh whatever its angles;
    the A15 background in the box of Gamma's samples fits and is the fallback."""
    from dolfinx_universal.meshing.plans_tet import GradedTetPlan, tet_plan

    surface = _superellipsoid(p, axes, 2.0)
    plan = tet_plan(comm, surface, 0.25, 3, None, 3.0, None, "auto", 5e6)
    assert isinstance(plan, GradedTetPlan) and plan.auto
    assert plan.alternative is not None and plan.alternative.estimate() > 5e6
    assert plan.compact is not None and plan.fallback(5e6) is plan.compact
    assert plan.compact.size == plan.alternative.size
