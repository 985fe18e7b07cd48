"""Plotting: gathering cells, straight and curved outlines, conforming-mesh figures."""

from __future__ import annotations

from mpi4py import MPI

import basix
import numpy as np
import pytest
from dolfinx import fem
from dolfinx import mesh as dmesh

import dolfinx_universal as du
from dolfinx_universal.boundaries import Circle, Domain
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
        # Outlines of an affine degree-k cell lie on its straight edges.
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
