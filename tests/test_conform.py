"""Conforming straight meshes: invariants, the method's quality bounds, MPI invariance, errors."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
import ufl
from conftest import needs_ranks
from dolfinx import fem
from dolfinx import mesh as dmesh
from scipy.spatial import cKDTree

import dolfinx_universal as du
from dolfinx_universal.backgrounds.lattice_tri import (
    create_background_mesh,
    equilateral_triangulation,
)
from dolfinx_universal.conforming.classify import signed_areas

comm = MPI.COMM_WORLD


def immersed_vertices(cm: du.ConformingMesh) -> np.ndarray:
    topo = cm.mesh.topology
    topo.create_connectivity(1, 0)
    fv = topo.connectivity(1, 0).array.reshape(-1, 2)[cm.facet_tags.find(du.IMMERSED)]
    return np.unique(fv)


@pytest.mark.parametrize("eta", [0.0, 0.2])
def test_circle_invariants(eta):
    R, c = 1.0, np.array([0.031, -0.017])
    h = R / 12
    bg = du.equilateral_mesh(comm, [[-1.5, -1.5], [1.5, 1.5]], h)
    cm = du.conform(bg, du.Circle(c, R), eta=eta)
    x = cm.x
    # Boundary vertices lie on the circle (they are closest points c + R u: rounding only, a
    # few ulps of R = 1; 1e-14 = 45 ulps).
    r = np.linalg.norm(x[immersed_vertices(cm)] - c, axis=1)
    assert np.abs(r - R).max() < 1e-14
    # Every conforming triangle keeps the orientation of its background triangle.
    cells = cm.cells
    assert np.all(np.sign(signed_areas(x, cells)) == np.sign(signed_areas(cm.background_x, cells)))
    # No vertex moves by more than alpha h (snapped ones by less than h, relaxed ones <= alpha h).
    bg_x = bg.geometry.x[:, :2]
    shift = np.linalg.norm(x - cm.background_x, axis=1)
    assert shift.max() <= h * (1 + 1e-12)  # (slack: rounding of the norms)
    # Vertices deeper than R_r do not move; the background boundary does not move.
    deep = np.linalg.norm(cm.background_x - c, axis=1) < R - 3 * h - 1e-9
    assert np.all(shift[deep] == 0)
    assert len(bg_x) >= len(x)  # no vertex added
    # The polygon's area converges to pi R^2 at rate h^2 (inscribed-polygon error ~ h^2/R).
    area = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(cm.mesh))))
    assert 0 < np.pi * R**2 - area < 2 * np.pi * R * h**2 / (8 * R) * 4
    rep = du.quality_report(cm)
    assert rep["n_inverted"] == 0
    assert rep["n_positively_cut"] == comm.allreduce(int(cm.positively_cut[: len(cells)].sum()))


def test_quality_bounds_trend():
    """The bounds of Rangarajan & Lew (2014): equilateral background, R_r = 3h, alpha = 3/4.

    They bound the images of M_h, so the relaxation (which trades the Q's for angles) is off.
    """
    for n in (24, 48):
        bg = du.equilateral_mesh(comm, [[-1.2, -1.2], [1.2, 1.2]], 1.0 / n)
        for eta in (0.0, 0.2):
            cm = du.conform(bg, du.Circle((0, 0), 1.0), eta=eta, relax=False)
            rep = du.quality_report(cm)
            assert rep["Q3_max"] <= 4 / 3 + 1e-12  # sharp bound: slack for rounding
            assert rep["Q2_max"] <= 2 * np.sqrt(13) / 3
            assert rep["Q1_max"] <= np.sqrt(13)
            assert rep["n_inverted"] == 0 and rep["theta_min_deg"] > 15


def test_default_parameters():
    bg = du.equilateral_mesh(comm, [[-1.5, -1.5], [1.5, 1.5]], 0.1)
    cm = du.conform(bg, du.Circle((0, 0), 1.0))
    assert cm.alpha == pytest.approx(0.75)
    assert np.allclose(cm.R_r, 0.3) and np.allclose(cm.h, 0.1)
    with pytest.raises(ValueError, match="alpha"):
        du.conform(bg, du.Circle((0, 0), 1.0), alpha=0.5)
    with pytest.raises(ValueError, match="R_r"):
        du.conform(bg, du.Circle((0, 0), 1.0), R_r=0.05)


def test_facet_tags_and_maps():
    bg = du.equilateral_mesh(comm, [[-1, -1], [1, 1]], 0.1)
    cm = du.conform(bg, du.Domain(None, [du.Circle((0.1, 0.0), 0.4)]))
    ds = ufl.ds(cm.mesh, subdomain_data=cm.facet_tags)
    inner = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ds(du.IMMERSED))))
    outer = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ds(du.OUTER))))
    assert inner == pytest.approx(2 * np.pi * 0.4, rel=5e-3)
    # The outer boundary is the background's own zig-zag polygon: it covers the box.
    assert outer > 8.0
    # cell_map / vertex_map point at the background cells / vertices the mesh came from.
    bg.topology.create_connectivity(2, 0)
    bg_cells = bg.topology.connectivity(2, 0).array.reshape(-1, 3)
    assert np.array_equal(bg_cells[cm.cell_map], cm.vertex_map[cm.cells])
    moved = cm.moved
    assert np.allclose(cm.x[~moved], cm.background_x[~moved])


def _points(msh) -> np.ndarray:
    """Owned geometry nodes of ``msh``, gathered (in the partition's order)."""
    n = msh.geometry.index_map().size_local
    return np.concatenate(msh.comm.allgather(msh.geometry.x[:n, :2]))


def _same_points(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    """Equal point sets up to ``atol``: one-to-one nearest neighbours.

    Order-free: a node computed by another cell (another partition) may differ in the last
    bits, and a sort, even on rounded values, could then order two nodes differently.
    """
    assert a.shape == b.shape
    dist, idx = cKDTree(b).query(a)
    assert dist.max(initial=0.0) <= atol, dist.max()
    assert len(np.unique(idx)) == len(a)


def _fingerprints(c: MPI.Comm) -> dict:
    """A disc, a spline domain and a container with a hole, conformed and curved on ``c``."""
    bg = du.equilateral_mesh(c, [[-1.6, -1.6], [1.6, 1.6]], 0.1)
    t = np.linspace(0, 2 * np.pi, 14, endpoint=False)
    r = 1 + 0.25 * np.sin(2 * t) + 0.1 * np.cos(5 * t)
    cases = {
        "circle": (du.conform(bg, du.Circle((0.013, -0.021), 1.0), eta=0.2), 3),
        "spline": (
            du.conform(bg, du.PeriodicSpline(np.column_stack([r * np.cos(t), r * np.sin(t)]))),
            2,
        ),
        "holed": (du.conform(bg, du.Domain(None, [du.Circle((0.2, 0.1), 0.5)])), 2),
    }
    out = {}
    for key, (cm, degree) in cases.items():
        cv = du.curved_mesh(cm, degree, "I")
        ds = ufl.ds(cv.mesh, subdomain_data=cv.facet_tags)
        nfo = cm.mesh.topology.index_map(1).size_local
        out[key] = {
            "quality": du.quality_report(cm),
            "vertices": _points(cm.mesh),
            "nodes": _points(cv.mesh),
            "area": c.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(cv.mesh)))),
            "length": c.allreduce(fem.assemble_scalar(fem.form(1.0 * ds(du.IMMERSED)))),
            "facets": [
                c.allreduce(int((cm.facet_tags.find(v) < nfo).sum()))
                for v in (du.IMMERSED, du.OUTER)
            ],
        }
    return out


@pytest.mark.mpi
@needs_ranks(2)
def test_same_mesh_on_any_number_of_ranks():
    ref, got = _fingerprints(MPI.COMM_SELF), _fingerprints(comm)
    for key in ref:
        a, b = ref[key], got[key]
        assert a["quality"]["n_cells"] == b["quality"]["n_cells"]
        assert a["facets"] == b["facets"]
        # Nodes computed by another cell or rank differ by rounding (a few ulps of |x| <= 1.6,
        # 1e-15); a changed mesh moves a vertex by >= 1e-9 h (TIE, steps >= 1e-2 h): 1e-11 h
        # lies two orders from both. Angles and ratios move by (rounding / h) ~ 1e-14.
        for q in ("theta_min_deg", "theta_max_deg", "q_max", "Q1_max", "Q2_max", "Q3_max"):
            assert a["quality"][q] == pytest.approx(b["quality"][q], rel=1e-12)
        _same_points(a["vertices"], b["vertices"], atol=1e-11 * 0.1)
        _same_points(a["nodes"], b["nodes"], atol=1e-11 * 0.1)
        assert a["area"] == pytest.approx(b["area"], rel=1e-11)  # sums in another order
        assert a["length"] == pytest.approx(b["length"], rel=1e-11)


# --- errors: each is raised with where and what to do -----------------------------------


def test_error_domain_leaves_background():
    bg = du.equilateral_mesh(comm, [[-1, -1], [1, 1]], 0.1)
    with pytest.raises(du.MeshingError, match="background"):
        du.conform(bg, du.Circle((0.9, 0.0), 0.5))
    # Entirely outside: nothing to keep / a body that is not in the background at all.
    with pytest.raises(du.MeshingError, match="background"):
        du.conform(bg, du.Domain(None, [du.Circle((5.0, 0.0), 0.5)]))
    # A hole close to the background boundary (inside the domain): that boundary would move.
    with pytest.raises(du.MeshingError, match="R_r"):
        du.conform(bg, du.Domain(None, [du.Circle((0.0, 0.0), 0.85)]))


def test_error_conditioning_angle():
    """Right-angled background triangles: some proximal vertex has a 90 degree angle."""
    bg = dmesh.create_rectangle(
        comm, [[-1.5, -1.5], [1.5, 1.5]], [30, 30], ghost_mode=dmesh.GhostMode.shared_facet
    )
    with pytest.raises(du.MeshingError, match="conditioning angle .* acute"):
        du.conform(bg, du.Circle((0.0123, 0.0456), 1.0))


def test_error_vertex_outside_not_on_positive_edge():
    """A hole smaller than the mesh around one vertex: it is outside but never snapped."""
    h = 0.1
    bg = du.equilateral_mesh(comm, [[-1, -1], [1, 1]], h)
    vertex = bg.geometry.x[np.argmin(np.linalg.norm(bg.geometry.x[:, :2], axis=1)), :2]
    vertex = np.array(comm.bcast(vertex if comm.rank == 0 else None, root=0))
    with pytest.raises(du.MeshingError, match="no positive edge"):
        du.conform(bg, du.Domain(None, [du.Circle(vertex + [0.01, 0.0], 0.02)]), eta=0.0)


def test_error_gamma_h_not_simple():
    """Two bodies closer than the mesh size: Gamma_h touches itself."""
    bg = du.equilateral_mesh(comm, [[-1, -1], [1, 1]], 0.1)
    bodies = [du.Circle((-0.31, 0.0), 0.3), du.Circle((0.31, 0.013), 0.3)]
    with pytest.raises(du.MeshingError, match="refine"):
        du.conform(bg, du.Domain(None, bodies))


def test_error_inverted_cell():
    """An obtuse background (non-acute near Gamma) folds when snapped: a clear error, no mesh.

    A nearly straight boundary y = 0 (the top of a flat ellipse) and a strip of flat obtuse
    triangles whose apex lies just above it: snapping the apex inverts the triangles below it.
    """
    xs = np.linspace(-1, 1, 21)
    rows = [
        np.column_stack([xs + (j % 2) * 0.05, np.full_like(xs, y)])
        for j, y in enumerate([-0.6, -0.3, -0.05, 0.02, 0.3, 0.6])
    ]
    x = np.concatenate(rows)
    n = len(xs)
    cells = []
    for j in range(len(rows) - 1):
        lo, up = j * n, (j + 1) * n
        for i in range(n - 1):
            cells += [[lo + i, lo + i + 1, up + i], [lo + i + 1, up + i + 1, up + i]]
    msh = create_background_mesh(comm, x, np.array(cells))
    flat = du.Ellipse((0.0, -0.25), 0.95, 0.25)  # top nearly straight at y = 0, inside
    with pytest.raises(du.MeshingError, match="inverted|acute|refine"):
        du.conform(msh, flat, eta=0.0, R_r=0.5)


class _NaNCircle(du.Circle):
    def project(self, x):
        phi, y = super().project(x)
        y[::7] = np.nan
        return phi, y


def test_error_nan():
    bg = du.equilateral_mesh(comm, [[-1.5, -1.5], [1.5, 1.5]], 0.1)
    with pytest.raises(du.MeshingError, match="NaN"):
        du.conform(bg, _NaNCircle((0.0, 0.0), 1.0))
    with pytest.raises(ValueError, match="NaN"):
        du.Circle((0.0, 0.0), 1.0).signed_distance(np.array([[np.nan, 0.0]]))


@pytest.mark.mpi
@needs_ranks(2)
def test_errors_raised_on_every_rank():
    """A failure detected on some ranks only raises on all ranks (no deadlock), with one
    message."""
    bg = du.equilateral_mesh(comm, [[-1, -1], [1, 1]], 0.1)
    with pytest.raises(du.MeshingError) as info:
        du.conform(bg, du.Circle((0.9, 0.0), 0.5))
    messages = comm.allgather(str(info.value))
    assert all(m == messages[0] for m in messages)


@pytest.mark.parametrize("hole", [False, True])
def test_vertices_exactly_on_gamma(hole):
    """A circle centred at a lattice vertex with radius 8h passes through six vertices; the
    sign test rounds some of them inside. They count as on Gamma (outside): a valid mesh."""
    h = 0.0125
    x, cells = equilateral_triangulation([[0, 0], [1, 1]], h)
    bg = create_background_mesh(comm, x, cells)
    centre = x[np.argmin(np.linalg.norm(x - [0.4, 0.4], axis=1))]
    circle = du.Circle(centre, 8 * h)
    cm = du.conform(bg, du.Domain(None, [circle]) if hole else circle, eta=0.0)
    assert du.quality_report(cm)["n_inverted"] == 0


def test_on_positive_edge_is_a_deprecated_name_of_on_gamma():
    bg = du.equilateral_mesh(MPI.COMM_SELF, [[-1, -1], [1, 1]], 0.2)
    cm = du.conform(bg, du.Circle((0.01, 0.02), 0.6))
    with pytest.warns(DeprecationWarning, match="on_gamma"):
        assert cm.on_positive_edge is cm.on_gamma
