"""Graded acute background meshes: stencils, balance, conformity, sizes and DOLFINx meshes."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
from conftest import needs_ranks
from test_background import canonical_cells, check_shared_facet_ghosts

import dolfinx_universal  # noqa: F401  (initialises the DOLFINx wheel before dolfinx imports)
from dolfinx_universal.backgrounds import graded_tri as gr
from dolfinx_universal.backgrounds.graded_tri import (
    EDGE_FACTOR,
    STENCIL_ANGLE_RANGE,
    acute_quadtree_triangulation,
    graded_mesh,
    local_size,
)
from dolfinx_universal.cells.tri import edge_lengths, interior_angles, signed_areas

BOX = [[-0.7, -0.7], [0.7, 0.7]]
H_FINE, H_COARSE, SLOPE = 0.01, 0.1, 0.5


def circle_size(p: np.ndarray) -> np.ndarray:
    """Fine (0.01) along the circle of radius 0.5, growing with slope 0.5 up to 0.1."""
    r = np.hypot(p[:, 0], p[:, 1])
    return np.clip(H_FINE + SLOPE * np.abs(r - 0.5), H_FINE, H_COARSE)


def edge_data(x: np.ndarray, cells: np.ndarray):
    """Unique edges, the number of triangles on each, and pairs of triangles sharing an edge."""
    e = np.sort(np.concatenate([cells[:, [0, 1]], cells[:, [1, 2]], cells[:, [2, 0]]]), axis=1)
    key = e[:, 0] * len(x) + e[:, 1]
    tri = np.tile(np.arange(len(cells)), 3)
    order = np.argsort(key, kind="stable")
    ks, ts = key[order], tri[order]
    same = ks[1:] == ks[:-1]
    pairs = np.column_stack([ts[:-1][same], ts[1:][same]])
    ukey, counts = np.unique(key, return_counts=True)
    edges = np.column_stack([ukey // len(x), ukey % len(x)])
    return edges, counts, pairs


def check_mesh(x: np.ndarray, cells: np.ndarray, box) -> dict:
    """Assert every structural property of an acute quadtree mesh; return statistics."""
    (x0, y0), (x1, y1) = box
    assert x.dtype == np.float64 and x.shape[1] == 2
    assert cells.dtype == np.int64 and cells.shape[1] == 3
    # Every vertex used, no duplicate vertices (exact and after rounding).
    assert np.array_equal(np.unique(cells), np.arange(len(x)))
    assert len(np.unique(x, axis=0)) == len(x)
    assert len(np.unique(np.round(x, 10), axis=0)) == len(x)
    assert x[:, 0].min() == x0 and x[:, 0].max() == x1
    assert x[:, 1].min() == y0 and x[:, 1].max() == y1
    # Counter-clockwise, area of the box.
    area = signed_areas(x, cells)
    assert area.min() > 0
    assert np.isclose(area.sum(), (x1 - x0) * (y1 - y0), rtol=1e-12)  # (sum of n areas: ulps)
    # Strictly acute, within the stencil range.
    ang = np.degrees(interior_angles(x, cells))
    assert np.allclose(ang.sum(axis=1), 180.0)
    lo, hi = STENCIL_ANGLE_RANGE
    assert ang.max() < 90.0
    assert lo - 1e-9 <= ang.min() and ang.max() <= hi + 1e-9
    # Conforming: interior edges in exactly two triangles, the others exactly on the box.
    edges, counts, pairs = edge_data(x, cells)
    assert counts.max() == 2
    b = x[edges[counts == 1]]  # (nb, 2 endpoints, 2)
    on_side = (
        ((b[:, :, 0] == x0).all(1))
        | ((b[:, :, 0] == x1).all(1))
        | ((b[:, :, 1] == y0).all(1))
        | ((b[:, :, 1] == y1).all(1))
    )
    assert on_side.all(), f"{(~on_side).sum()} boundary edges off the box (hanging vertices)"
    interior = x[edges[counts == 2]]
    assert not (
        ((interior[:, :, 0] == x0).all(1))
        | ((interior[:, :, 0] == x1).all(1))
        | ((interior[:, :, 1] == y0).all(1))
        | ((interior[:, :, 1] == y1).all(1))
    ).any()
    perimeter = np.linalg.norm(b[:, 0] - b[:, 1], axis=1).sum()
    assert np.isclose(perimeter, 2 * ((x1 - x0) + (y1 - y0)), rtol=1e-12)  # (a sum: ulps)
    # A triangulated disc: V - E + F = 1.
    assert len(x) - len(edges) + len(cells) == 1
    # Neighbouring triangles: diameters differ at most by 1 / sin(min angle) (law of sines).
    diam = edge_lengths(x, cells).max(axis=1)
    ratio = np.maximum(diam[pairs[:, 0]] / diam[pairs[:, 1]], diam[pairs[:, 1]] / diam[pairs[:, 0]])
    assert ratio.max() <= 1.0 / np.sin(np.radians(lo)) + 1e-12  # (slack for rounding)
    return {
        "min_angle": ang.min(),
        "max_angle": ang.max(),
        "num_cells": len(cells),
        "neighbour_ratio": ratio.max(),
    }


def check_sizes(x, cells, size, slope: float):
    """Longest edges against the size at the triangle centroid (``size`` ``slope``-Lipschitz).

    The leaf of side s holding a triangle satisfies EDGE_FACTOR s <= h at the nearest of its
    nine sample points, within s sqrt(2)/4 of the centroid c, so every edge is at most
    ``EDGE_FACTOR / (EDGE_FACTOR - slope sqrt(2)/4) h(c)``. From below, transition stencils
    carry triangles of their finer neighbours, so diameters reach down to about 0.1 h.
    """
    e = edge_lengths(x, cells)
    h = size(x[cells].mean(axis=1))
    upper = EDGE_FACTOR / (EDGE_FACTOR - slope * np.sqrt(2) / 4)
    ratio = e.max(axis=1) / h
    assert ratio.max() <= upper
    assert ratio.min() >= 0.1
    return ratio.min(), ratio.max()


# ------------------------------------------------------------------------------------------
# Stencils
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mask", range(16))
def test_stencil(mask):
    pts, tris, nb = gr._STENCILS[mask]
    bnd = gr._boundary_points(mask)
    assert np.array_equal(pts[:nb], bnd / 4.0)
    on_bnd = (pts == 0) | (pts == 1)
    assert on_bnd[:nb].any(axis=1).all() and not on_bnd[nb:].any()
    area = signed_areas(pts, tris)
    assert area.min() > 0 and np.isclose(area.sum(), 1.0, rtol=1e-13)  # (a few areas: ulps)
    ang = np.degrees(interior_angles(pts, tris))
    assert ang.max() < 75.0 and ang.min() > 36.0
    # Stencil boundary: the square's sides split exactly at the prescribed points.
    edges, counts, _ = edge_data(pts, tris)
    assert counts.max() == 2
    bedges = edges[counts == 1]
    assert bedges.max() < nb and len(bedges) == nb
    # Each boundary point has exactly the two perimeter neighbours as boundary edges.
    t = np.select(  # position along the perimeter, 0..15
        [bnd[:, 1] == 0, bnd[:, 0] == 4, bnd[:, 1] == 4, bnd[:, 0] == 0],
        [bnd[:, 0], 4 + bnd[:, 1], 12 - bnd[:, 0], (16 - bnd[:, 1]) % 16],
    )
    order = np.argsort(t)
    expected = np.sort(np.column_stack([order, np.roll(order, -1)]), axis=1)
    assert np.array_equal(np.unique(expected, axis=0), np.unique(np.sort(bedges, axis=1), axis=0))
    # Fine corners carry the points at 1/4 on both sides; every side has its midpoint.
    for c in range(4):
        corner = gr._CORNERS[c]
        nxt = corner + (gr._CORNERS[(c + 1) % 4] - corner) // 4
        has = (bnd == nxt).all(axis=1).any()
        assert has == bool(mask >> c & 1)
    assert all((bnd == m).all(axis=1).any() for m in gr._MIDS)


def test_mask0_is_exact():
    pts, tris, _ = gr._STENCILS[0]
    ang = np.sort(np.round(np.degrees(interior_angles(pts, tris)), 9).ravel())
    assert set(np.unique(ang)) == {45.0, 54.0, 63.0, 72.0}


def test_stencil_rotations_consistent():
    """Rotating a stencil by a quarter turn gives the stencil of the rotated mask."""
    for m in range(16):
        pts, tris, nb = gr._STENCILS[m]
        rot = np.column_stack([1 - pts[:, 1], pts[:, 0]])
        pts2, _, nb2 = gr._STENCILS[gr._rotate_mask(m, 1)]
        assert nb == nb2
        assert np.allclose(np.sort(rot[:nb], axis=0), np.sort(pts2[:nb2], axis=0))


def test_angle_range():
    lo, hi = STENCIL_ANGLE_RANGE
    print(f"stencil angles in [{lo:.2f}, {hi:.2f}] degrees")
    assert 36.9 < lo < hi < 73.9
    assert 0.5 < EDGE_FACTOR < 0.55


# ------------------------------------------------------------------------------------------
# Quadtree
# ------------------------------------------------------------------------------------------


def leaf_level_grid(leaves, nx, ny):
    """Level of the leaf covering each cell of the finest grid, and how often it is covered."""
    finest = len(leaves) - 1
    grid = np.full((nx << finest, ny << finest), -1)
    cover = np.zeros(grid.shape, dtype=int)
    for level, keys in enumerate(leaves):
        g = np.full((nx << level, ny << level), -1)
        g[keys // (ny << level), keys % (ny << level)] = level
        f = 1 << (finest - level)
        up = g.repeat(f, axis=0).repeat(f, axis=1)
        grid = np.maximum(grid, up)
        cover += up >= 0
    return grid, cover


@pytest.mark.parametrize("nx, ny", [(1, 1), (2, 1), (1, 3)])
def test_balance(nx, ny):
    """Leaves sharing a vertex differ by at most one level, and the leaves tile the box."""
    side = 1.0

    # A size jump (not Lipschitz): the size-driven tree is far from balanced.
    def size(p):
        return np.where((p[:, 0] < 0.3) & (p[:, 1] < 0.2), 0.0015, 0.5)

    h = gr._target_size(size, side, None, None)
    raw = gr._refine(h, 0.0, 0.0, side, side, nx, ny)
    refined = gr._balance(raw, nx, ny)
    for a, b in zip(raw, refined):  # balancing only adds splits
        assert np.isin(a, b).all()
    leaves = gr._leaves(refined, nx, ny)
    grid, cover = leaf_level_grid(leaves, nx, ny)
    assert (cover == 1).all()  # the leaves tile the box
    pairs = [
        (grid[1:, :], grid[:-1, :]),
        (grid[:, 1:], grid[:, :-1]),
        (grid[1:, 1:], grid[:-1, :-1]),
        (grid[1:, :-1], grid[:-1, 1:]),
    ]
    for a, b in pairs:  # fine cells touching (edge or corner) lie in leaves one level apart
        assert np.abs(a - b).max() <= 1
    # The unbalanced tree really needed balancing for this size function.
    assert sum(map(len, refined)) > sum(map(len, raw))


# ------------------------------------------------------------------------------------------
# Meshes
# ------------------------------------------------------------------------------------------


def test_circle_size():
    x, cells = acute_quadtree_triangulation(BOX, circle_size)
    stats = check_mesh(x, cells, BOX)
    lo, hi = check_sizes(x, cells, circle_size, SLOPE)
    print(
        f"circle: {stats['num_cells']} cells, angles [{stats['min_angle']:.2f}, "
        f"{stats['max_angle']:.2f}], longest edge / h in [{lo:.3f}, {hi:.3f}], "
        f"neighbour diameter ratio <= {stats['neighbour_ratio']:.3f}"
    )
    # Fine along the circle, coarse in the corners.
    ls = local_size(x, cells)
    r = np.hypot(x[:, 0], x[:, 1])
    assert ls[np.abs(r - 0.5) < 0.005].max() <= 1.5 * H_FINE
    assert ls[(np.abs(x) > 0.55).all(axis=1)].min() > 0.4 * H_COARSE


@pytest.mark.parametrize("h", [0.05, 0.013])
def test_constant_size(h):
    x, cells = acute_quadtree_triangulation(BOX, h)
    stats = check_mesh(x, cells, BOX)
    e = edge_lengths(x, cells)
    # One leaf size s in (h / (2 EDGE_FACTOR), h / EDGE_FACTOR], all leaves of stencil 0
    # (edges between 0.295 s and EDGE_FACTOR s).
    assert e.max() <= h and e.min() >= 0.27 * h
    assert np.isclose(stats["min_angle"], 45.0) and np.isclose(stats["max_angle"], 72.0)


@pytest.mark.parametrize("seed", range(4))
def test_random_size_functions(seed):
    rng = np.random.default_rng(seed)
    box = [[0.0, 0.0], [2.0, 1.0]] if seed % 2 else [[-1.0, 2.0], [0.5, 3.5]]
    (x0, y0), (x1, y1) = box
    centres = rng.uniform([x0, y0], [x1, y1], size=(3, 2))
    radii = rng.uniform(0.05, 0.4, 3)
    hmin = rng.uniform(0.004, 0.02, 3)
    slope = rng.uniform(0.2, 0.6)
    hmax = rng.uniform(0.08, 0.3)

    def size(p):
        d = np.abs(np.linalg.norm(p[:, None, :] - centres[None], axis=2) - radii)
        return np.minimum((hmin + slope * d).min(axis=1), hmax)

    x, cells = acute_quadtree_triangulation(box, size)
    stats = check_mesh(x, cells, box)
    check_sizes(x, cells, size, slope)
    assert stats["num_cells"] > 1000


def test_min_max_size_and_rectangle():
    box = [[0.0, 0.0], [3.0, 1.0]]
    # max_size forces refinement where the size function is coarse.
    x, cells = acute_quadtree_triangulation(box, 10.0, max_size=0.1)
    check_mesh(x, cells, box)
    assert edge_lengths(x, cells).max() <= 0.1
    # min_size stops refinement where the size function is tiny.
    x, cells = acute_quadtree_triangulation(box, lambda p: np.full(len(p), 1e-9), min_size=0.05)
    check_mesh(x, cells, box)
    assert edge_lengths(x, cells).min() >= 0.27 * 0.05
    # A single root square: 14 triangles.
    x, cells = acute_quadtree_triangulation([[0, 0], [1, 1]], 5.0)
    check_mesh(x, cells, [[0, 0], [1, 1]])
    assert len(cells) == 14


def test_invalid_input():
    with pytest.raises(ValueError, match="whole number"):
        acute_quadtree_triangulation([[0, 0], [1.5, 1]], 0.1)
    with pytest.raises(ValueError, match="finite box"):
        acute_quadtree_triangulation([[0, 0], [0, 1]], 0.1)
    with pytest.raises(ValueError, match="positive"):
        acute_quadtree_triangulation(BOX, -1.0)
    with pytest.raises(ValueError, match="positive"):
        acute_quadtree_triangulation(BOX, lambda p: np.zeros(len(p)))
    with pytest.raises(ValueError, match="min_size"):
        acute_quadtree_triangulation(BOX, 0.1, min_size=0.2, max_size=0.1)


def test_local_size():
    x, cells = acute_quadtree_triangulation(BOX, circle_size)
    ls = local_size(x, cells)
    e = edge_lengths(x, cells).max(axis=1)
    brute = np.zeros(len(x))
    for t, d in zip(cells, e):
        brute[t] = np.maximum(brute[t], d)
    assert np.array_equal(ls, brute)
    assert np.array_equal(local_size(np.zeros((2, 2)), np.empty((0, 3))), np.zeros(2))


# ------------------------------------------------------------------------------------------
# DOLFINx meshes
# ------------------------------------------------------------------------------------------


def test_graded_mesh_serial():
    comm = MPI.COMM_WORLD
    msh = graded_mesh(comm, BOX, circle_size)
    x, cells = acute_quadtree_triangulation(BOX, circle_size)
    assert msh.topology.index_map(2).size_global == len(cells)
    assert msh.topology.index_map(0).size_global == len(x)
    if comm.size == 1:
        geo = msh.geometry.x[:, :2]
        assert np.array_equal(np.unique(geo, axis=0), np.unique(x, axis=0))


@pytest.mark.mpi
@needs_ranks(2)
def test_graded_mesh_mpi():
    msh = graded_mesh(MPI.COMM_WORLD, BOX, circle_size)
    imap = msh.topology.index_map(2)
    c = MPI.COMM_WORLD
    _, cells = acute_quadtree_triangulation(BOX, circle_size)
    assert imap.size_global == c.allreduce(imap.size_local) == len(cells)
    assert c.allreduce(imap.num_ghosts) > 0


@pytest.mark.mpi
@needs_ranks(2)
@pytest.mark.parametrize(
    "box, size, options",
    [
        (BOX, circle_size, {}),
        ([[0.0, 0.0], [2.0, 1.0]], 0.05, {}),
        ([[0.0, 0.0], [1.3, 0.7]], circle_size, {"root_size": 0.1}),
        ([[0.0, 0.0], [1.0, 1.0]], 5.0, {}),  # one leaf: ranks without cells
    ],
)
def test_graded_mesh_distributed(box, size, options):
    """Built in parallel (each rank tiles its run of leaves), the same cells with bitwise
    the same coordinates as on one rank, balanced over the ranks, with shared-facet ghosts."""
    c = MPI.COMM_WORLD
    msh = graded_mesh(c, box, size, **options)
    serial = graded_mesh(MPI.COMM_SELF, box, size, **options)
    a, b = canonical_cells(msh), canonical_cells(serial)
    if c.rank == 0:
        assert a.shape == b.shape and np.array_equal(a, b)
    n = c.allgather(msh.topology.index_map(2).size_local)
    # A run holds the leaves starting in its share of the triangles: it is within one leaf
    # (at most 56 triangles) of an equal share.
    assert max(n) - min(n) < 2 * 56
    assert msh.topology.index_map(0).size_global == serial.topology.index_map(0).size_global
    check_shared_facet_ghosts(msh, serial)


def test_balance_in_blocks(monkeypatch):
    """The balance sweep in small blocks of leaves gives the same triangulation."""
    x, cells = acute_quadtree_triangulation(BOX, circle_size)
    monkeypatch.setattr(gr, "_CHUNK", 7)
    x7, cells7 = acute_quadtree_triangulation(BOX, circle_size)
    assert np.array_equal(x, x7) and np.array_equal(cells, cells7)


@pytest.mark.mpi
@needs_ranks(2)
def test_graded_mesh_size_error_on_some_ranks():
    """A size function failing on the points of one rank only raises on every rank."""

    def size(p):
        if np.any(p[:, 0] > 0.6):  # the last slice of the root cells' samples only
            raise RuntimeError("no size there")
        return np.full(len(p), 0.05)

    with pytest.raises(ValueError, match="no size there"):
        graded_mesh(MPI.COMM_WORLD, [[0.0, 0.0], [1.0, 1.0]], size, root_size=0.1)
