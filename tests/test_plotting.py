"""Plotting: gathering cells, straight and curved outlines, conforming-mesh figures."""

from __future__ import annotations

import sys

from mpi4py import MPI

import basix
import numpy as np
import pytest
from conftest import needs_ranks
from dolfinx import fem
from dolfinx import mesh as dmesh

import dolfinx_universal as du
from dolfinx_universal.boundaries.curves import Circle
from dolfinx_universal.boundaries.domains import Domain
from dolfinx_universal.plotting import (
    boundary_polyline,
    cell_outlines,
    gather_cells,
    plot_conforming,
    plot_mesh,
    save,
)

pytest.importorskip("matplotlib")
from matplotlib.figure import Figure  # noqa: E402

comm = MPI.COMM_WORLD
PNG = b"\x89PNG\r\n\x1a\n"


def curved_copy(msh: dmesh.Mesh, k: int) -> dmesh.Mesh:
    element = fem.coordinate_element(dmesh.CellType.triangle, k, basix.LagrangeVariant.gll_warped)
    return fem.interpolate_geometry(msh, element)


def assert_png(path) -> None:
    if comm.rank == 0:
        data = path.read_bytes()
        assert data[:8] == PNG and len(data) > 2000


@pytest.mark.parametrize("shape", [(2, 3), (5, 4)])
def test_gather_cells_straight(shape):
    msh = dmesh.create_rectangle(comm, [[0.0, 0.0], [2.0, 1.0]], shape)
    imc = msh.topology.index_map(2)
    ncl = imc.size_local + imc.num_ghosts
    nodes, values = gather_cells(msh, np.arange(ncl, dtype=np.float64) + 10 * comm.rank)
    nodes_only = gather_cells(msh)
    if comm.rank != 0:
        assert nodes is None and values is None and nodes_only is None
        return
    assert nodes.shape == (imc.size_global, 3, 2) and values.shape == (imc.size_global,)
    np.testing.assert_array_equal(nodes, nodes_only)
    d1, d2 = nodes[:, 1] - nodes[:, 0], nodes[:, 2] - nodes[:, 0]
    area = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    assert area.sum() == pytest.approx(2.0)


@pytest.mark.parametrize("k", [2, 3])
def test_gather_cells_curved(k):
    msh = curved_copy(dmesh.create_unit_square(comm, 3, 2), k)
    nodes = gather_cells(msh)
    if comm.rank == 0:
        assert nodes.shape == (12, (k + 1) * (k + 2) // 2, 2)
        # Outlines of an affine degree-k cell lie on its straight edges (Lagrange basis sums of
        # O(1) nodes: a few ulps; 1e-14 = 45 ulps).
        out = cell_outlines(nodes, k, points_per_edge=5)
        assert out.shape == (12, 15, 2)
        np.testing.assert_allclose(out[:, [0, 5, 10]], nodes[:, :3], atol=1e-14)
        v = nodes[:, :3]
        for e, (a, b) in enumerate([(0, 1), (1, 2), (2, 0)]):
            seg = out[:, 5 * e : 5 * (e + 1)]
            d = v[:, b] - v[:, a]
            w = seg - v[:, None, a]
            cross = d[:, None, 0] * w[..., 1] - d[:, None, 1] * w[..., 0]
            assert np.abs(cross).max() < 1e-13


def test_curved_edge_is_drawn_curved():
    """A degree-2 cell with a displaced mid-node has a curved outline through that node."""
    nodes = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.6, 0.6], [0.0, 0.5], [0.5, 0.0]]])
    out = cell_outlines(nodes, 2, points_per_edge=8)  # infers nothing: degree given
    # (tolerances 1e-14: Lagrange basis sums of O(1) nodes, a few ulps; the curve is 1e-3 off)
    np.testing.assert_array_equal(cell_outlines(nodes), out)  # degree inferred from 6 nodes
    edge = out[0, 8:16]  # vertex 1 -> vertex 2: the edge of mid-node 3
    off_chord = np.abs(edge.sum(axis=1) - 1.0) / np.sqrt(2)  # distance to the line x + y = 1
    assert off_chord[0] < 1e-14 and np.all(off_chord[1:] > 1e-3)
    np.testing.assert_allclose(edge[4], [0.6, 0.6], atol=1e-14)  # t = 1/2: the mid-node
    # The two other edges stay straight.
    assert np.abs(out[0, :8, 1]).max() < 1e-14 and np.abs(out[0, 16:, 0]).max() < 1e-14
    with pytest.raises(ValueError):
        cell_outlines(np.zeros((1, 5, 2)))


@pytest.mark.parametrize("k", [1, 2])
def test_plot_mesh_png(tmp_path, k):
    msh = dmesh.create_unit_square(comm, 4, 4)
    if k > 1:
        msh = curved_copy(msh, k)
        msh.geometry.x[:, 1] += 0.1 * np.sin(np.pi * msh.geometry.x[:, 0])
    imc = msh.topology.index_map(2)
    nodes, values = gather_cells(msh, np.arange(imc.size_local + imc.num_ghosts))
    path = tmp_path / f"mesh{k}.png"
    if comm.rank == 0:
        fig = Figure()
        ax = fig.add_subplot()
        coll = plot_mesh(ax, nodes, k, values=values, cmap="viridis")
        assert coll is not None and len(coll.get_paths()) == len(nodes)
        assert ax.get_xlim()[1] >= 1.0
        save(fig, path)
    else:
        assert plot_mesh(None, nodes, k) is None
        save(None, path)
    assert_png(path)


def test_plot_conforming(tmp_path):
    bg = du.equilateral_mesh(comm, [[-1.5, -1.5], [1.5, 1.5]], 0.25)
    cm = du.conform(bg, Circle([0.0, 0.0], 1.0))
    fig, ax = plot_conforming(None, cm, title="circle")
    if comm.rank == 0:
        assert ax.get_xlim()[0] < -1.5 and ax.get_title() == "circle"
    save(fig, tmp_path / "bg.png")
    assert_png(tmp_path / "bg.png")

    curved = du.curved_mesh(cm, 2)
    fig, ax = plot_conforming(None, cm, show_background=False, mesh=curved.mesh)
    if comm.rank == 0:
        ax.set_xlim(0.5, 1.1)
    save(fig, tmp_path / "zoom.png")
    assert_png(tmp_path / "zoom.png")
    if comm.rank != 0:
        assert fig is None and ax is None


def test_boundary_polyline():
    circle = Circle([1.0, 2.0], 0.5)
    line = boundary_polyline(circle, 100)
    assert line.shape == (101, 2) and np.isfinite(line).all()
    np.testing.assert_array_equal(line[0], line[-1])
    np.testing.assert_allclose(np.linalg.norm(line - [1.0, 2.0], axis=1), 0.5)


def test_boundary_polyline_several_curves():
    domain = Domain(Circle([0.0, 0.0], 1.0), [Circle([0.3, 0.1], 0.2)])
    line = boundary_polyline(domain, 2000)
    gap = np.flatnonzero(np.isnan(line[:, 0]))
    assert len(gap) == 1  # two closed curves
    for piece in (line[: gap[0]], line[gap[0] + 1 :]):
        np.testing.assert_array_equal(piece[0], piece[-1])


# --- Curved drawing, fields, legends, large meshes -------------------------------------------

from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.colors import to_rgba  # noqa: E402

from dolfinx_universal.plotting import (  # noqa: E402
    GAMMA_H_COLOR,
    cell_edges,
    field_triangulation,
    plot_function,
    reference_lattice,
    unique_edges,
)


def disc(h: float = 0.25):
    bg = du.equilateral_mesh(comm, [[-1.5, -1.5], [1.5, 1.5]], h)
    return du.conform(bg, Circle([0.0, 0.0], 1.0))


def triangle_area(points, triangles) -> np.ndarray:
    a = points[triangles]
    d1, d2 = a[:, 1] - a[:, 0], a[:, 2] - a[:, 0]
    return 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


def gamma_h_segments(ax) -> np.ndarray:
    target = to_rgba(GAMMA_H_COLOR)
    colls = [
        c
        for c in ax.collections
        if isinstance(c, LineCollection) and np.allclose(c.get_colors()[0], target)
    ]
    assert len(colls) == 1
    return colls[0].get_segments()


def test_reference_lattice():
    for n in (1, 2, 5):
        pts, tris = reference_lattice(n)
        assert pts.shape == ((n + 1) * (n + 2) // 2, 2) and tris.shape == (n * n, 3)
        area = triangle_area(pts, tris)
        assert np.all(area > 0) and area.sum() == pytest.approx(0.5)


@pytest.mark.parametrize("k", [1, 3])
def test_gamma_h_is_drawn_curved(k):
    """The drawn Gamma_h of a degree-3 disc lies on the circle, the straight one O(h^2) off."""
    cm = disc(0.1)
    mesh = du.curved_mesh(cm, k) if k > 1 else None
    fig, ax = plot_conforming(None, cm, show_background=False, mesh=mesh, inset=False)
    if comm.rank != 0:
        assert fig is None
        return
    segs = gamma_h_segments(ax)
    pts = np.concatenate(segs)
    r = np.linalg.norm(pts, axis=1)
    # Degree-3 interpolation of the unit circle over chords of about h = 0.1: O(h^4 / 100),
    # 1.0e-6 measured (relaxed vertices on Gamma lengthen some chords).
    assert np.abs(r - 1.0).max() < (2e-6 if k == 3 else 1e-12 + 1.0)
    chords = np.array([np.linalg.norm(s[-1] - s[0]) for s in segs])
    assert np.isclose(chords.sum(), 2 * np.pi, rtol=1e-2)  # the whole circle
    if k == 1:  # straight edges: chord midpoints are h^2 / 8 inside the circle
        mid = np.linalg.norm([0.5 * (s[0] + s[-1]) for s in segs], axis=1)
        dev = 1.0 - mid
        assert dev.max() > 1e-4 and np.allclose(dev, chords**2 / 8, rtol=0.05)
    else:
        assert all(len(s) > 2 for s in segs)


def test_field_covers_curved_cells():
    cm = disc(0.3)
    cv = du.curved_mesh(cm, 3)
    V = fem.functionspace(cv.mesh, ("Lagrange", 2))
    u = fem.Function(V, name="u")
    u.interpolate(lambda x: np.sin(2 * x[0]) + x[1] ** 2)
    import ufl

    area = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(cv.mesh))))
    nodes = gather_cells(cv.mesh)
    errors = {}
    for n in (12, 224):
        pts, tris, vals = field_triangulation(u, curved_subdivisions=n)
        if comm.rank == 0:
            a = triangle_area(pts, tris)
            assert a.min() > 0  # no folded sub-triangle
            errors[n] = abs(a.sum() - area)
            if n == 12:  # exactly the region enclosed by the drawn (curved) cell edges
                lines, on_boundary, _ = unique_edges(cell_edges(nodes, 3, 12))
                loop = lines[on_boundary].reshape(-1, 2)  # repeated points add no area
                order = np.argsort(np.arctan2(loop[:, 1], loop[:, 0]))
                x, y = loop[order].T
                enclosed = 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
                assert a.sum() == pytest.approx(enclosed, abs=1e-12)  # two sums: rounding
    if comm.rank == 0:
        assert errors[224] < 1e-6 and errors[12] < 1e-3
    straight = field_triangulation(u, subdivisions=1, curved_subdivisions=1)
    if comm.rank == 0:  # straight triangles leave O(h^2) slivers along Gamma
        assert area - triangle_area(straight[0], straight[1]).sum() > 1e-3
    if comm.size == 1:  # the values are u's, evaluated through its dofs and basis
        from dolfinx_universal.plotting import curved_cells

        pts, _, vals = field_triangulation(u, subdivisions=3, curved_subdivisions=5)
        curved = curved_cells(nodes)  # straight cells come first, 10 points each, then 21
        cells = np.concatenate(
            [np.repeat(np.flatnonzero(~curved), 10), np.repeat(np.flatnonzero(curved), 21)]
        )
        assert len(cells) == len(pts) and curved.sum() > 10
        p3 = np.column_stack([pts, np.zeros(len(pts))])
        # the same basis functions evaluated twice (DOLFINx, the plot's tabulation): rounding
        np.testing.assert_allclose(u.eval(p3, cells.astype(np.int32))[:, 0], vals, atol=1e-12)


def test_plot_function_png(tmp_path):
    cm = disc(0.3)
    cv = du.curved_mesh(cm, 3)
    V = fem.functionspace(cv.mesh, ("Lagrange", 2, (2,)))
    u = fem.Function(V, name="u")
    u.interpolate(lambda x: np.stack([-x[1], x[0]]))
    fig, ax = plot_function(
        None, u, boundary=cm.boundary, show_mesh=True, inset=(0.5, 0.5, 0.9, 0.9), title="u"
    )
    path = tmp_path / "field.png"
    save(fig, path)
    assert_png(path)
    if comm.rank == 0:
        assert ax.get_xlabel() == "x" and ax.get_ylabel() == "y"
        assert len(ax.child_axes) == 1 and ax.get_title() == "u"
        assert fig.axes[-1].get_ylabel() == "|u|"  # the colorbar


def test_plot_function_active_cells():
    bg = du.equilateral_mesh(comm, [[-1.5, -1.5], [1.5, 1.5]], 0.3)
    from dolfinx_universal.moving.domain import MovingDomain

    md = MovingDomain(bg, degree=2)
    md.update(Circle([0.1, 0.0], 0.8))
    V = fem.functionspace(md.mesh, ("Lagrange", 1))
    u = fem.Function(V)
    u.interpolate(lambda x: x[0])
    import ufl

    area = comm.allreduce(fem.assemble_scalar(fem.form(md.active * ufl.dx(md.mesh))))
    for kwargs in ({"active": md.active}, {"cells": md.active_cells}):
        pts, tris, _ = field_triangulation(u, curved_subdivisions=64, **kwargs)
        if comm.rank == 0:
            assert triangle_area(pts, tris).sum() == pytest.approx(area, abs=1e-4)
    fig, ax = plot_function(None, u, active=md.active)
    if comm.rank == 0:
        assert ax.get_xlim()[1] < 1.2  # the inactive background is not drawn


def test_legend_and_labels():
    cm = disc(0.25)
    curved = du.curved_mesh(cm, 2)
    figures = [  # collective: every rank calls, rank 0 draws
        plot_conforming(None, cm, mesh=curved),
        plot_conforming(None, cm, legend=False, inset=False),
        plot_conforming(None, cm),
    ]
    if comm.rank != 0:
        assert all(f == (None, None) for f in figures)
        return
    ax = figures[0][1]
    assert ax.get_xlabel() == "x" and ax.get_ylabel() == "y"
    assert ax.get_aspect() == 1.0
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(s.startswith("curved, degree 2") for s in labels)
    assert any("Gamma_h" in s for s in labels) and any("exact" in s for s in labels)
    assert any("unaltered" in s for s in labels) and any("moved" in s for s in labels)
    assert len(ax.child_axes) == 1  # the automatic zoom of a new figure
    ax = figures[1][1]
    assert ax.get_legend() is None and not ax.child_axes
    labels = [t.get_text() for t in figures[2][1].get_legend().get_texts()]
    assert any("positively cut" in s for s in labels)  # degree 1: nothing curved


def test_large_mesh_thin_lines_and_inset(tmp_path):
    msh = dmesh.create_unit_square(comm, 100, 100)  # 20000 cells
    nodes = gather_cells(msh)
    path = tmp_path / "big.png"
    if comm.rank == 0:
        fig = Figure(figsize=(6, 6))
        ax = fig.add_subplot()
        plot_mesh(ax, nodes, facecolors="#dbe7f3")
        lines = [c for c in ax.collections if isinstance(c, LineCollection)]
        assert len(lines) == 1 and lines[0].get_linewidths()[0] < 0.15
        assert len(lines[0].get_segments()) == 30200  # each edge once
        plot_mesh(Figure().add_subplot(), nodes, max_edge_cells=10000)
        from dolfinx_universal.plotting import add_inset

        add_inset(ax, (0.4, 0.4, 0.5, 0.5), lambda a: plot_mesh(a, nodes, linewidth=0.8))
        assert len(ax.child_axes) == 1
        save(fig, path)
    assert_png(path)


def test_large_conforming_mesh_inset(tmp_path):
    bg = du.equilateral_mesh(comm, [[-1.2, -1.2], [1.2, 1.2]], 0.02)
    cm = du.conform(bg, Circle([0.0, 0.0], 1.0))
    assert cm.mesh.topology.index_map(2).size_global > 15000
    fig, ax = plot_conforming(None, cm, show_background=False, inset=(0.6, 0.6, 0.75, 0.75))
    if comm.rank == 0:
        lines = [c for c in ax.collections if isinstance(c, LineCollection)]
        assert max(c.get_linewidths()[0] for c in lines if len(c.get_segments()) > 5000) < 0.15
        assert len(ax.child_axes) == 1
    save(fig, tmp_path / "big_conforming.png")
    assert_png(tmp_path / "big_conforming.png")


def _drawn(c: MPI.Comm, png) -> dict | None:
    """Draw a curved disc and a field on ``c``; what rank 0 drew (None elsewhere)."""
    from dolfinx_universal.plotting import GAMMA_H_COLOR, field_triangulation

    bg = du.equilateral_mesh(c, [[-1.5, -1.5], [1.5, 1.5]], 0.25)
    cm = du.conform(bg, du.Circle([0.0, 0.0], 1.0))
    cv = du.curved_mesh(cm, 3)
    fig, ax = plot_conforming(None, cm, mesh=cv, title=f"{c.size} ranks")
    V = fem.functionspace(cv.mesh, ("Lagrange", 2))
    u = fem.Function(V, name="u")
    u.interpolate(lambda x: x[0] ** 2 - x[1])
    pts, tris, vals = field_triangulation(u)
    fig2, ax2 = plot_function(None, u, show_mesh=True)
    if c.rank != 0:
        assert fig is None and ax is None and pts is None and fig2 is None
        return None
    save(fig, png)
    gamma = [
        col
        for col in ax.collections
        if isinstance(col, LineCollection)
        and np.allclose(col.get_colors()[0], to_rgba(GAMMA_H_COLOR))
    ]
    a = pts[tris]
    d1, d2 = a[:, 1] - a[:, 0], a[:, 2] - a[:, 0]
    return {
        "num_cells": len(ax.collections[1].get_paths()),
        "num_gamma_segments": len(gamma[0].get_segments()),
        "legend": len(ax.get_legend().get_texts()),
        "field_area": float((0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])).sum()),
        "field_points": len(pts),
    }


@pytest.mark.mpi
@needs_ranks(2)
def test_plot_mpi(mpi_tmp_path):
    parallel = _drawn(MPI.COMM_WORLD, mpi_tmp_path / "mesh.png")
    serial = _drawn(MPI.COMM_SELF, mpi_tmp_path / f"serial{MPI.COMM_WORLD.rank}.png")
    if MPI.COMM_WORLD.rank == 0:
        for key in ("num_cells", "num_gamma_segments", "legend", "field_points"):
            assert parallel[key] == serial[key], key
        # the same triangles summed in another order: sqrt(n) to n ulps
        assert parallel["field_area"] == pytest.approx(serial["field_area"], rel=1e-11)
        assert (mpi_tmp_path / "mesh.png").read_bytes()[:8] == PNG


def test_missing_matplotlib_message(monkeypatch):
    import dolfinx_universal.plotting as plotting

    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(ImportError, match=r"pip install dolfinx_universal\[plot\]"):
        plotting._mpl()


# ------------------------------------------------------------------------------- tetrahedra
def _enclosed(faces: np.ndarray) -> float:
    """Volume enclosed by outward triangles ``(m, 3, 3)`` (divergence theorem)."""
    return float((faces[:, 0] * np.cross(faces[:, 1], faces[:, 2])).sum() / 6.0)


@pytest.mark.mpi
def test_gather_and_clip_tetrahedra():
    """Every owned cell once, exterior faces marked, and the clipped set's faces closed."""
    from dolfinx_universal.plotting import clipped_faces, gather_tetrahedra

    msh = dmesh.create_box(
        comm, [[0.0, 0.0, 0.0], [2.0, 1.0, 1.0]], (4, 2, 2), dmesh.CellType.tetrahedron
    )
    data = gather_tetrahedra(msh)  # no tags: the exterior faces
    if comm.rank != 0:
        assert data is None
        return
    n = 4 * 2 * 2 * 6
    assert data["corners"].shape == (n, 4, 3) and data["vertices"].shape == (n, 4)
    assert data["tagged"].sum() == 2 * (4 * 2 + 4 * 2 + 2 * 2) * 2
    assert np.all((data["min_dihedral_deg"] > 0) & (data["min_dihedral_deg"] <= 70.6))
    assert len(np.unique(data["vertices"])) == 5 * 3 * 3
    faces, cells = clipped_faces(data, (1.0, 0.5, 0.5), (1.0, 0.0, 0.0))
    centroid_x = data["corners"].mean(axis=1)[:, 0]
    assert set(cells) <= set(np.flatnonzero(centroid_x <= 1.0))
    # outward and closed: they enclose the kept half, x <= 1 (cells of whole cubes)
    assert _enclosed(faces) == pytest.approx(1.0, rel=1e-12)
    assert len(faces) == 6 * 4 * 2  # the unit cube's 6 sides of 2 x 2 squares, 2 triangles each


def test_plot_tetrahedra(tmp_path):
    from matplotlib.figure import Figure

    from dolfinx_universal.plotting import plot_tetrahedra

    cm = du.conform(
        du.a15_mesh(comm, [[-1.6] * 3, [1.6] * 3], 0.4), du.Sphere((0.01, 0.02, 0.03), 1.0)
    )
    fig, ax = plot_tetrahedra(cm, title="clipped")  # a new figure, Gamma_h's tags
    if comm.rank == 0:
        assert isinstance(fig, Figure) and ax.name == "3d" and ax.get_title() == "clipped"
        assert len(ax.collections) == 1 and len(fig.axes) == 2  # the faces, a colour bar
        save(fig, tmp_path / "clipped.png")
        assert_png(tmp_path / "clipped.png")
    else:
        assert fig is None and ax is None
    target = Figure() if comm.rank == 0 else None
    ax3 = target.add_subplot(projection="3d") if target is not None else None
    fig, ax = plot_tetrahedra(cm, ax3, view="surface", colorbar=False, vmin=30, vmax=70)
    if comm.rank == 0:
        assert fig is target and ax is ax3
        # the surface view draws Gamma_h: the IMMERSED faces
        nf = cm.mesh.topology.index_map(2).size_local
        drawn = len(ax.collections[0].get_facecolors())
        assert drawn == int((cm.facet_tags.find(du.IMMERSED) < nf).sum()) or comm.size > 1
    with pytest.raises(ValueError, match="'clipped' or 'surface'"):
        plot_tetrahedra(cm, view="slice")
    with pytest.raises(ValueError, match="tetrahedron mesh"):
        plot_tetrahedra(dmesh.create_unit_square(comm, 2, 2))
