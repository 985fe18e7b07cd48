"""The topology of a surface counted on a grid: its components and genus from the voxels of
the solid it bounds."""

from __future__ import annotations

from itertools import combinations, product

import numpy as np
import numpy.typing as npt
from scipy import ndimage

__all__ = ["grid_topology"]


def grid_topology(inside: npt.NDArray[np.bool_]) -> tuple[int, int]:
    """Number of components and total genus of the surface of a voxelised solid.

    ``inside (n0, n1, n2)``: the grid points in the solid, none on the grid's faces. The
    solid is the cubical complex of these points (6-connected: edges, squares and cubes
    whose corners are all inside); its Euler characteristic ``chi = V - E + F - C`` is half
    that of its surface. The surface has one component per component of the solid and per
    cavity (a 26-connected component of the outside points other than the exterior), and
    total genus ``components - chi``. Right when the grid resolves the solid's parts and
    the gaps between them.
    """
    b = np.asarray(inside, dtype=bool)
    v = int(b.sum())
    e = sum(int((b[s0] & b[s1]).sum()) for s0, s1 in _corners(1))
    f = sum(int(np.logical_and.reduce([b[s] for s in q]).sum()) for q in _corners(2))
    c = int(np.logical_and.reduce([b[s] for s in _corners(3)[0]]).sum())
    chi = v - e + f - c
    solids = ndimage.label(b)[1]
    outside = ndimage.label(~b, structure=np.ones((3, 3, 3)))[1]
    components = solids + outside - 1
    return components, components - chi


def _corners(k: int) -> list[tuple[tuple[slice, ...], ...]]:
    """Index tuples of the corners of the edges (k = 1), unit squares (2) or cubes (3) of a
    3D grid, one entry per orientation."""
    out = []
    for axes in combinations(range(3), k):
        corners = []
        for offset in product((0, 1), repeat=k):
            sl = [slice(None)] * 3
            for a, o in zip(axes, offset):
                sl[a] = slice(o, None if o else -1)
            corners.append(tuple(sl))
        out.append(tuple(corners))
    return out
