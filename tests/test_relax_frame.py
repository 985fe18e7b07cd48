"""The relaxation's frame: with ``relax_frame="body"`` a motion that maps the background
onto itself maps the relaxed mesh onto the relaxed mesh (triangles and tetrahedra)."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
from conftest import needs_ranks
from scipy.spatial import cKDTree

import dolfinx_universal as du
from dolfinx_universal.conforming.relax import FRAME_GRID, RelaxFrame

comm = MPI.COMM_WORLD
THETA = 0.3


def _images(background, cm) -> tuple[np.ndarray, np.ndarray]:
    """Background positions and relaxed images of the kept vertices, gathered from every
    rank (each vertex from its owner)."""
    gdim = background.geometry.dim
    owned = cm.vertex_map < background.topology.index_map(0).size_local
    x0 = background.geometry.x[cm.vertex_map[owned], :gdim]
    y = cm.x[: len(cm.vertex_map)][owned, :gdim]
    c = background.comm
    return np.concatenate(c.allgather(x0)), np.concatenate(c.allgather(y))


def half_turn_gap(background, domain, centre, turn, **options) -> float:
    """Largest distance between the relaxed mesh of ``domain(THETA + pi)`` and the
    half-turned relaxed mesh of ``domain(THETA)`` (vertex by vertex); ``turn`` maps a
    point's offset from ``centre`` to its half-turned offset."""
    um = du.UniversalMesh(background, **options)
    xa, ya = _images(background, um.conform(domain(THETA)))
    xb, yb = _images(background, um.conform(domain(THETA + np.pi)))
    dist, image = cKDTree(xb).query(centre + (xa - centre) @ turn.T)
    both = dist < 1e-12  # kept at both positions
    assert both.sum() > 0.9 * len(xa)
    gap = np.linalg.norm(yb[image[both]] - (centre + (ya[both] - centre) @ turn.T), axis=1)
    return float(gap.max())


def triangles():
    """An ellipse turning about a vertex of an equilateral background (the triangular
    lattice is symmetric under the half turn about any of its vertices)."""
    bg = du.equilateral_mesh(comm, [[-1.0, -0.9], [1.0, 0.9]], 0.05)
    x0 = bg.geometry.x[:, :2]
    local = x0[np.argmin(np.linalg.norm(x0, axis=1))]
    nearest = comm.allgather((float(np.linalg.norm(local)), tuple(local)))
    centre = np.array(min(nearest)[1])
    ellipse = du.Ellipse(tuple(centre), 0.6, 0.3)

    def domain(theta):
        return du.Domain(None, [du.RigidMotion(ellipse, angle=theta, center=tuple(centre))])

    return bg, domain, centre, -np.eye(2), {}


def tetrahedra():
    """A tilted ellipsoid turning about the z axis in a sphere, on an A15 background
    symmetric under the half turn about that axis (that of demos/stokes_moving_3d.py)."""
    bg = du.a15_mesh(comm, [[-1.2] * 3, [1.2] * 3], 0.25)
    ellipsoid = du.Ellipsoid((0.0, 0.0, 0.0), (0.45, 0.35, 0.3), rotation=(0.4, 0.6, 0.2))
    container = du.Sphere((0.0, 0.0, 0.0), 1.0)

    def domain(theta):
        return du.Domain(container, [du.RigidMotion(ellipsoid, angle=theta)])

    return bg, domain, np.zeros(3), np.diag([-1.0, -1.0, 1.0]), {"eta": 0.5}


@pytest.mark.parametrize("case", [triangles, tetrahedra])
def test_body_frame_relaxation_is_equivariant(case):
    """``"body"``: the relaxed meshes half a turn apart are each other's half turn to
    rounding (seen: 1.2e-15 on triangles, 2.9e-14 on tetrahedra; bound 1e-12, far below
    the smallest relaxation step, about 1e-3 h). ``"world"`` (the default: priorities and
    directions fixed in space) makes other choices at the two positions (seen: 1.6e-2 and
    4.9e-2), so the bound is not met by accident."""
    bg, domain, centre, turn, options = case()
    assert half_turn_gap(bg, domain, centre, turn, relax_frame="body", **options) < 1e-12
    assert half_turn_gap(bg, domain, centre, turn, **options) > 1e-6


def test_frame_priority_snaps_rounding():
    """Frame coordinates that differ by rounding hash alike (the grid is fixed, the same on
    every rank); a grid step apart they do not."""
    c, s = np.cos(0.7), np.sin(0.7)
    frame = RelaxFrame(np.array([[c, -s], [s, c]]), np.array([0.1, -0.2]))
    x = np.random.default_rng(0).uniform(-2, 2, (1000, 2))
    p = frame.priority(x)
    assert np.array_equal(p, frame.priority(x * (1 + 1e-15)))
    assert not np.array_equal(p, frame.priority(x + 3 * FRAME_GRID))
    assert ((p >= 0) & (p < 1)).all() and len(np.unique(p)) == len(p)
    with pytest.raises(ValueError, match="relax_frame"):
        du.UniversalMesh(du.equilateral_mesh(comm, [[0, 0], [1, 1]], 0.25), relax_frame="x")


@pytest.mark.mpi
@needs_ranks(2)
def test_body_frame_same_mesh_on_any_ranks():
    """The frame's priorities are a function of coordinates only: the same relaxed mesh on
    one rank and on all (compared by background vertex)."""
    sizes = []
    for c in (comm, MPI.COMM_SELF):
        bg = du.equilateral_mesh(c, [[-1.0, -0.9], [1.0, 0.9]], 0.05)
        ellipse = du.Ellipse((0.01, 0.02), 0.6, 0.3)
        um = du.UniversalMesh(bg, relax_frame="body")
        x0, y = _images(bg, um.conform(du.Domain(None, [du.RigidMotion(ellipse, angle=THETA)])))
        rows = np.column_stack([np.round(x0, 9), y])
        sizes.append(rows[np.lexsort(rows[:, 1::-1].T)])
    assert sizes[0].shape == sizes[1].shape
    np.testing.assert_allclose(sizes[0], sizes[1], rtol=0, atol=1e-13)
