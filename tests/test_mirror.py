"""Mirror-symmetric universal meshes: the background's root rows and mirrored stencils, the
relaxation's symmetric choices, and ``mesh_domain(mirror=...)``, serial and distributed.

Symmetry is checked on point sets: every node in the mirrored band has a node at its mirror
image. Images are computed in floating point (``2 a - y``), and the nodes of the two halves
are computed by different but mirrored operations, so they agree to a few ulps of the
coordinates (about 1e-16 here); a broken symmetry moves nodes by a fraction of a cell
(1e-3 and more). The tolerance 1e-12 lies between the two on any machine.
"""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
from conftest import needs_ranks
from scipy.spatial import cKDTree
from test_background import canonical_cells

import dolfinx_universal as du
from dolfinx_universal.backgrounds import graded_tri as gr
from dolfinx_universal.cells.tri import interior_angles, signed_areas
from dolfinx_universal.conforming.relax import RelaxFrame
from dolfinx_universal.conforming.universal import _mirror_frame

comm = MPI.COMM_WORLD
LENGTH, HEIGHT = 2.2, 0.41
CENTRE, RADIUS = (0.2, 0.2), 0.05
MIRROR = (CENTRE, (0.0, 1.0))
BOX = [[0.0, 0.0], [LENGTH, HEIGHT]]
SYMMETRIC = 1e-12
"""Largest distance from a node's mirror image to the nearest node: rounding (see above)."""


def cylinder_size(p: np.ndarray) -> np.ndarray:
    """Fine at the cylinder, growing by 0.2 per unit length; symmetric about y = 0.2."""
    d = np.abs(np.hypot(p[:, 0] - CENTRE[0], p[:, 1] - CENTRE[1]) - RADIUS)
    return np.minimum(0.004 + 0.2 * d, 0.1)


def asymmetry(x: np.ndarray, band: float, axis: int = 1, a: float = CENTRE[1]) -> float:
    """Largest distance from the mirror image of a point within ``band`` of the line to the
    nearest point of ``x``."""
    near = np.abs(x[:, axis] - a) < band
    image = x[near].copy()
    image[:, axis] = 2.0 * a - image[:, axis]
    return float(cKDTree(x).query(image)[0].max())


# ------------------------------------------------------------------------------------------
# The background
# ------------------------------------------------------------------------------------------


def test_root_rows_of_a_channel():
    """The channel's rows about y = 0.2: 0.1, 0.1 | 0.1, 0.11 (root cells of 0.1 by 0.1, 22
    columns); the line is a root boundary, exactly; the outer row is within MAX_STRETCH."""
    bx, by, axis, k = gr._mirror_breaks(BOX, 0.387, MIRROR)
    assert axis == 1 and by[k] == 0.2 and k == 2  # one row of 0.1 mirrored on each side
    assert np.allclose(np.diff(by), [0.1, 0.1, 0.1, 0.11]) and len(bx) == 23
    assert by[0] == 0.0 and by[-1] == HEIGHT and bx[0] == 0.0 and bx[-1] == LENGTH
    rows, cols = np.diff(by), np.diff(bx)
    assert max(rows.max() / cols.min(), cols.max() / rows.min()) <= gr.MAX_STRETCH * (1 + 1e-9)
    # A vertical line: columns of 0.2, five mirrored on each side.
    bx, by, axis, k = gr._mirror_breaks(BOX, 0.2, ((1.0, 0.0), (1.0, 0.0)))
    assert axis == 0 and bx[k] == 1.0 and k == 5 and np.allclose(np.diff(bx), 0.2)


def test_bad_mirrors():
    with pytest.raises(ValueError, match="normal to a coordinate axis"):
        gr.acute_quadtree_triangulation(BOX, 0.1, mirror=((0.2, 0.2), (1.0, 1.0)))
    with pytest.raises(ValueError, match="does not cross the box"):
        gr.acute_quadtree_triangulation(BOX, 0.1, mirror=((0.2, 0.5), (0.0, 1.0)))
    with pytest.raises(ValueError, match="finite numbers each"):
        gr.acute_quadtree_triangulation(BOX, 0.1, mirror=((0.2, np.nan), (0.0, 1.0)))


@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("mask", range(16))
def test_mirrored_stencil(axis, mask):
    """The mirrored stencil of a mask: the mirror image of the stencil of the reflected mask,
    with the mask's boundary points in their canonical order, counter-clockwise, acute."""
    pts, tris, nb = gr._MIRRORED[axis][mask]
    ref, ref_tris, ref_nb = gr._STENCILS[gr._reflect_mask(mask, axis)]
    assert nb == ref_nb and np.array_equal(pts[:nb], gr._boundary_points(mask) / 4.0)
    image = ref.copy()
    image[:, axis] = 1.0 - image[:, axis]
    assert np.allclose(np.sort(image, axis=0), np.sort(pts, axis=0), atol=1e-15)
    area = signed_areas(pts, tris)
    assert area.min() > 0 and np.isclose(area.sum(), 1.0, rtol=1e-13)
    angles = [
        np.sort(np.degrees(interior_angles(p, t)).ravel())
        for p, t in ((pts, tris), (ref, ref_tris))
    ]
    assert np.allclose(*angles, atol=1e-12)


def test_symmetric_triangulation():
    """A symmetric size in a channel: the mirrored rows' vertices and triangles are mirror
    images of each other; the mesh is valid, acute and covers the box. Without the mirror
    the same size gives an asymmetric mesh (what the test would see if the mirror broke)."""
    x, cells = gr.acute_quadtree_triangulation(BOX, cylinder_size, max_size=0.1, mirror=MIRROR)
    area = signed_areas(x, cells)
    assert area.min() > 0 and np.isclose(area.sum(), LENGTH * HEIGHT, rtol=1e-13)
    lo, hi = gr.STRETCHED_ANGLE_RANGE
    ang = np.degrees(interior_angles(x, cells))
    assert lo - 1e-9 <= ang.min() and ang.max() <= hi + 1e-9
    assert len(np.unique(x, axis=0)) == len(x)
    # Within the mirrored rows (0.1 on each side), but off the leaves touching their outer
    # edge (the leaves beyond it differ, and so can the fine corners there): 0.09.
    assert asymmetry(x, 0.09) < SYMMETRIC
    assert asymmetry(x[cells].mean(axis=1), 0.09) < SYMMETRIC
    x0, _ = gr.acute_quadtree_triangulation(BOX, cylinder_size, max_size=0.1, root_size=0.1)
    assert asymmetry(x0, 0.09) > 1e-3


@pytest.mark.mpi
@needs_ranks(2)
def test_symmetric_graded_mesh_distributed():
    """The same mirrored background on any number of ranks, bitwise."""
    msh = gr.graded_mesh(comm, BOX, cylinder_size, max_size=0.1, mirror=MIRROR)
    serial = gr.graded_mesh(MPI.COMM_SELF, BOX, cylinder_size, max_size=0.1, mirror=MIRROR)
    a, b = canonical_cells(msh), canonical_cells(serial)
    if comm.rank == 0:
        assert a is not None and b is not None
        assert a.shape == b.shape and np.array_equal(a, b)


# ------------------------------------------------------------------------------------------
# The relaxation and mesh_domain
# ------------------------------------------------------------------------------------------


def test_mirror_priorities():
    """A vertex and its image: one priority up to the last bit, which orders them; sides."""
    frame = _mirror_frame(MIRROR, 2)
    x = np.random.default_rng(3).uniform([0, 0], [1, 0.4], (100, 2))
    image = x.copy()
    image[:, 1] = 0.4 - image[:, 1]
    p, q = frame.priority(x), frame.priority(image)
    bits = np.ldexp(p, 53).astype(np.int64), np.ldexp(q, 53).astype(np.int64)
    assert np.array_equal(bits[0] >> 1, bits[1] >> 1)
    assert np.array_equal(bits[0] & 1, (x[:, 1] > 0.2).astype(np.int64))
    assert len(np.unique(p)) == len(p)
    assert np.array_equal(frame.side(x), np.sign(x[:, 1] - 0.2).astype(np.int64))
    assert frame.side(np.array([[0.7, 0.2]]))[0] == 0
    assert RelaxFrame(np.eye(2), np.zeros(2)).side(x).min() == 1


def _channel(mirror, degree: int = 2, relax: bool = True) -> du.MeshedDomain:
    domain = du.Domain(container=None, bodies=[du.Circle(CENTRE, RADIUS)])
    return du.mesh_domain(
        comm, domain, 0.1, degree=degree, box=BOX, size_field=cylinder_size, mirror=mirror,
        relax=relax,
    )  # fmt: skip


def _nodes(md: du.MeshedDomain) -> np.ndarray:
    """All nodes of the mesh on every rank."""
    x = md.mesh.geometry.x[: md.mesh.geometry.index_map().size_local, :2]
    return np.concatenate(comm.allgather(x))


def test_mesh_domain_mirror():
    """mesh_domain with the cylinder's axis as mirror: the curved mesh (every node, the
    vertices moved by M_h and by the relaxation, the nodes on the circle) is its own mirror
    image within the mirrored rows; without the mirror it is not (the relaxation's colours
    and directions break the symmetry), though M_h alone keeps it."""
    md = _channel(MIRROR)
    x = _nodes(md)
    assert asymmetry(x, 0.09) < SYMMETRIC
    assert md.certificate.min_angle_deg >= 30.0
    on = md.facet_tags.find(du.IMMERSED)
    assert md.mesh.comm.allreduce(len(on)) > 0
    unmirrored = _nodes(_channel(None))
    assert asymmetry(unmirrored, 0.09) > 1e-4
    # The relaxation is what breaks it: a background symmetric about the line but no
    # mirror given to the conforming step.
    plain = _channel(MIRROR, relax=False)
    assert asymmetry(_nodes(plain), 0.09) < SYMMETRIC


def test_mesh_domain_mirror_errors():
    with pytest.raises(ValueError, match="normal to a coordinate axis"):
        _channel(((0.2, 0.2), (0.6, 0.8)))
    with pytest.raises(ValueError, match="curves only"):
        du.mesh_domain(comm, du.Sphere((0, 0, 0), 0.5), 0.2, mirror=((0, 0, 0), (0, 0, 1)))
    bg = du.graded_mesh(comm, BOX, 0.05, root_size=0.1)
    with pytest.raises(ValueError, match="relax_frame='world'"):
        du.UniversalMesh(bg, mirror=MIRROR, relax_frame="body")
    with pytest.raises(ValueError, match="normal nonzero"):
        du.UniversalMesh(bg, mirror=((0.2, 0.2), (0.0, 0.0)))
    tets = du.a15_mesh(comm, [[0, 0, 0], [1, 1, 1]], 0.5)
    with pytest.raises(ValueError, match="triangles only"):
        du.UniversalMesh(tets, mirror=((0, 0, 0), (0, 0, 1)))


@pytest.mark.mpi
@needs_ranks(2)
def test_mesh_domain_mirror_distributed():
    """The same symmetric mesh on any number of ranks: nodes as point sets (nodes computed
    by another cell differ by a few ulps; a changed mesh by far more than 1e-12)."""
    x = _nodes(_channel(MIRROR))
    serial_md = du.mesh_domain(
        MPI.COMM_SELF, du.Domain(container=None, bodies=[du.Circle(CENTRE, RADIUS)]), 0.1,
        degree=2, box=BOX, size_field=cylinder_size, mirror=MIRROR,
    )  # fmt: skip
    ref = serial_md.mesh.geometry.x[:, :2]
    assert x.shape == ref.shape
    dist, idx = cKDTree(ref).query(x)
    assert dist.max() <= SYMMETRIC and len(np.unique(idx)) == len(x)
    assert asymmetry(x, 0.09) < SYMMETRIC
