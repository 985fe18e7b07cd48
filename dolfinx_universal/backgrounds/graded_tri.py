"""Graded acute background meshes: corner-balanced quadtrees tiled with acute stencils."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import mesh as dmesh

from dolfinx_universal.backgrounds.lattice_tri import create_mesh, layout_partitioner
from dolfinx_universal.cells.tri import cell_diameters, edge_lengths, interior_angles, signed_areas
from dolfinx_universal.core.arrays import distinct_rows, mirror_line

__all__ = [
    "EDGE_FACTOR",
    "MAX_STRETCH",
    "STENCIL_ANGLE_RANGE",
    "STRETCHED_ANGLE_RANGE",
    "acute_quadtree_triangulation",
    "graded_mesh",
    "local_size",
    "mirror_axis",
]

SizeLike = float | Callable[[npt.NDArray[np.float64]], npt.ArrayLike]

# ---------------------------------------------------------------------------------------------
# Stencils
# ---------------------------------------------------------------------------------------------
#
# Every leaf of the quadtree is the unit square [0, 1]^2 scaled by its side s. Its boundary
# points are
#
#   * the four corners and the four side midpoints (always), and
#   * for every *fine* corner (a corner touched by a leaf smaller than this one), the two points
#     at distance s/4 from that corner along the two sides meeting there.
#
# A leaf is therefore described by a 4-bit corner mask (bit c: corner c is fine, corners
# counter-clockwise from (0, 0)); the boundary point sets of neighbouring leaves agree (see
# ``_leaf_corner_masks``), so the stencils glue into a conforming triangulation. Because the
# two sides meeting at a corner always carry their first point at the same distance (s/2, or
# s/4 at a fine corner), no stencil has to resolve a 1:2 jump of the boundary spacing at a
# 90-degree corner; the jumps sit at side midpoints, where 180 degrees are available.
#
# Up to rotation there are six masks: 0, 1, 3, 5, 7 and 15.
#
# * Mask 0 is exact: the Steiner points (a, a), (1-b, b), (1-a, 1-a), (b, 1-b) with
#   a = tan72 / (2 (1 + tan72)) and b = tan63 / (2 (1 + tan63)) (a pinwheel: the corner
#   triangle (0,0), (1/2,0), (a,a) has angles 45, 72, 63 and (1,0), (1/2,0), (1-b,b) has 45,
#   63, 72; the rest follows by the quarter-turn symmetry) give twelve 45-63-72 triangles and
#   an inner quadrilateral split into two 54-72-54 triangles.
# * Mask 15 is four copies of mask 0 at half scale (the four quadrants).
# * Masks 1, 3, 5 and 7 (one to three fine corners) were designed numerically, once, offline:
#   the initial guess puts a half-scale mask-0 quadrant at every fine corner and the mask-0
#   Steiner point at every other corner; the Steiner points were then optimised (simulated
#   annealing over positions and number of points, each candidate triangulated by Delaunay,
#   followed by SLSQP on the fixed connectivity) to minimise
#   max(max_angle - 60, 0.6 (60 - min_angle)). Results (Steiner points, triangles, angle
#   range in degrees): mask 1: 7, 22, [36.93, 73.84]; mask 3: 9, 28, [38.84, 72.70];
#   mask 5: 9, 28, [37.66, 73.40]; mask 7: 11, 34, [39.32, 72.41] (masks 0 and 15: 4 and 21
#   points, 14 and 56 triangles, [45, 72]). The resulting coordinates and triangles are
#   stored below; ``_check_stencil`` verifies them at import. An acute triangulation is the
#   (unique) Delaunay triangulation of its vertices, so the stored connectivity is the only
#   one these points admit.

_TA, _TB = np.tan(np.radians(72.0)), np.tan(np.radians(63.0))
_A, _B = _TA / (2.0 * (1.0 + _TA)), _TB / (2.0 * (1.0 + _TB))

_CORNERS = np.array([[0, 0], [4, 0], [4, 4], [0, 4]])  # in quarter units
_MIDS = np.array([[2, 0], [4, 2], [2, 4], [0, 2]])

# Mask 0 in unit-square coordinates: 4 corners, 4 midpoints, 4 Steiner points.
_MASK0_POINTS = np.vstack(
    [
        _CORNERS / 4.0,
        _MIDS / 4.0,
        [[_A, _A], [1.0 - _B, _B], [1.0 - _A, 1.0 - _A], [_B, 1.0 - _B]],
    ]
)
_MASK0_CELLS = np.array(
    [
        [0, 4, 8], [0, 8, 7], [4, 1, 9], [1, 5, 9], [5, 2, 10], [2, 6, 10], [6, 3, 11],
        [3, 7, 11], [4, 9, 8], [5, 10, 9], [6, 11, 10], [7, 8, 11], [8, 9, 10], [8, 10, 11],
    ]
)  # fmt: skip

# Steiner points (unit square) and triangles (indices into boundary points, ordered as in
# ``_boundary_points(mask)``, followed by the Steiner points) of the numerically designed
# stencils. Filled in below.
_DESIGNED: dict[int, tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]] = {}
# <designed-stencils>
# mask 1: 7 Steiner points, 22 triangles, angles in [36.93, 73.84]
_DESIGNED[1] = (
    np.array(
        [
            [0.19085818851785616, 0.14846351575404662],
            [0.23703515574117004, 0.3684472962938206],
            [0.29244492985506876, 0.6109262018162858],
            [0.3502867531410259, 0.16398956095438808],
            [0.40500648217180546, 0.40609091718986234],
            [0.6403390244946627, 0.6409954748045801],
            [0.6109262018162894, 0.29244492985506076],
        ]
    ),
    np.array(
        [
            [0, 8, 10], [0, 10, 9], [1, 5, 16], [1, 16, 4], [2, 6, 15], [2, 15, 5],
            [3, 7, 12], [3, 12, 6], [4, 13, 8], [4, 16, 13], [5, 15, 16], [6, 12, 15],
            [7, 9, 11], [7, 11, 12], [8, 13, 10], [9, 10, 11], [10, 13, 11], [11, 13, 14],
            [11, 14, 12], [12, 14, 15], [13, 16, 14], [14, 16, 15],
        ]
    ),
)  # fmt: skip
# mask 3: 9 Steiner points, 28 triangles, angles in [38.84, 72.70]
_DESIGNED[3] = (
    np.array(
        [
            [0.20849666269409653, 0.3418550078752756],
            [0.17667476270354635, 0.15924155460242675],
            [0.32788892694261274, 0.6721110730573824],
            [0.40368273501933144, 0.18880418391994902],
            [0.6721110730573902, 0.6721110730573864],
            [0.5789306911278582, 0.19106839002984533],
            [0.7915033373058972, 0.34185500787527584],
            [0.8233252372964603, 0.15924155460240358],
            [0.4984102202655004, 0.43822509853216984],
        ]
    ),
    np.array(
        [
            [0, 8, 13], [0, 13, 9], [1, 10, 19], [1, 19, 11], [2, 6, 16], [2, 16, 5],
            [3, 7, 14], [3, 14, 6], [4, 11, 17], [4, 15, 8], [4, 17, 15], [5, 16, 18],
            [5, 18, 10], [6, 14, 16], [7, 9, 12], [7, 12, 14], [8, 15, 13], [9, 13, 12],
            [10, 18, 19], [11, 19, 17], [12, 13, 15], [12, 15, 20], [12, 20, 14], [14, 20, 16],
            [15, 17, 20], [16, 20, 18], [17, 18, 20], [17, 19, 18],
        ]
    ),
)  # fmt: skip
# mask 5: 9 Steiner points, 28 triangles, angles in [37.66, 73.40]
_DESIGNED[5] = (
    np.array(
        [
            [0.16225787947070558, 0.16225787947070533],
            [0.17877243153393893, 0.3471386855959466],
            [0.3245157589414068, 0.6754842410585951],
            [0.34723858850523304, 0.19986893589773194],
            [0.6528613144040795, 0.8212275684660783],
            [0.6754842410585724, 0.32451575894142176],
            [0.48788527361385964, 0.5121147263861517],
            [0.8377421205292872, 0.837742120529297],
            [0.8001310641022786, 0.6527614114947561],
        ]
    ),
    np.array(
        [
            [0, 8, 12], [0, 12, 9], [1, 5, 17], [1, 17, 4], [2, 10, 19], [2, 19, 11],
            [3, 7, 14], [3, 14, 6], [4, 15, 8], [4, 17, 15], [5, 11, 20], [5, 20, 17],
            [6, 14, 16], [6, 16, 10], [7, 9, 13], [7, 13, 14], [8, 15, 12], [9, 12, 13],
            [10, 16, 19], [11, 19, 20], [12, 15, 13], [13, 15, 18], [13, 18, 14], [14, 18, 16],
            [15, 17, 18], [16, 18, 20], [16, 20, 19], [17, 20, 18],
        ]
    ),
)  # fmt: skip
# mask 7: 11 Steiner points, 34 triangles, angles in [39.32, 72.41]
_DESIGNED[7] = (
    np.array(
        [
            [0.17204275341374056, 0.16203461665034966],
            [0.2016028653095733, 0.33887868044250147],
            [0.32926230769248616, 0.6707376923075153],
            [0.3729587530025891, 0.19063533749856365],
            [0.6611213195575, 0.7983971346904276],
            [0.7999762682454542, 0.3812382536460094],
            [0.832365685379897, 0.16363899058271272],
            [0.8379653833496369, 0.8279572465862606],
            [0.5042070786554906, 0.49579292134450864],
            [0.6333195124419793, 0.1956160257735489],
            [0.8093646625014418, 0.6270412469974046],
        ]
    ),
    np.array(
        [
            [0, 8, 14], [0, 14, 9], [1, 10, 20], [1, 20, 11], [2, 12, 21], [2, 21, 13],
            [3, 7, 16], [3, 16, 6], [4, 11, 23], [4, 17, 8], [4, 23, 17], [5, 13, 24],
            [5, 19, 10], [5, 24, 19], [6, 16, 18], [6, 18, 12], [7, 9, 15], [7, 15, 16],
            [8, 17, 14], [9, 14, 15], [10, 19, 20], [11, 20, 23], [12, 18, 21], [13, 21, 24],
            [14, 17, 15], [15, 17, 22], [15, 22, 16], [16, 22, 18], [17, 23, 22], [18, 22, 24],
            [18, 24, 21], [19, 22, 23], [19, 23, 20], [19, 24, 22],
        ]
    ),
)  # fmt: skip
# </designed-stencils>


def _boundary_points(mask: int) -> npt.NDArray[np.int64]:
    """Boundary points of the stencil with fine-corner ``mask``, in quarter units.

    Corners, side midpoints, then for each fine corner ``c`` (ascending) the points at distance
    1/4 towards corner ``c + 1`` and towards corner ``c - 1``.
    """
    pts = [_CORNERS, _MIDS]
    for c in range(4):
        if mask >> c & 1:
            v, nxt, prv = _CORNERS[c], _CORNERS[(c + 1) % 4], _CORNERS[(c - 1) % 4]
            pts.append(np.array([v + (nxt - v) // 4, v + (prv - v) // 4]))
    return np.vstack(pts).astype(np.int64)


def _mask15() -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Steiner points and triangles of the all-fine stencil: mask 0 in each quadrant."""
    bnd = _boundary_points(15) / 4.0
    pts = [bnd]
    blocks: list[npt.NDArray[np.int64]] = []
    for q in _CORNERS / 8.0:  # quadrant origins (0,0), (1/2,0), (1/2,1/2), (0,1/2)
        pts.append(q + 0.5 * _MASK0_POINTS)
        blocks.append(_MASK0_CELLS + len(bnd) + 12 * len(blocks))
    x = np.vstack(pts)
    key = np.round(x * 2**20).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    # Renumber: boundary points first (their order in ``bnd``), then the others in order.
    order = np.argsort(first)  # unique points in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    cells = rank[inverse.ravel()][np.vstack(blocks)]
    steiner = x[np.sort(first)][len(bnd) :]
    return steiner, cells.astype(np.int64)


def _rotate_mask(mask: int, r: int) -> int:
    """Corner mask after ``r`` quarter turns counter-clockwise (corner c -> corner c + r)."""
    r %= 4
    return ((mask << r) | (mask >> (4 - r))) & 15


def _check_stencil(
    mask: int, steiner: npt.NDArray[np.float64], cells: npt.NDArray[np.int64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Orient a stencil counter-clockwise and verify that it tiles the unit square acutely."""
    x = np.vstack([_boundary_points(mask) / 4.0, steiner])
    cells = np.asarray(cells, dtype=np.int64)
    area = signed_areas(x, cells)
    cells = np.where((area < 0)[:, None], cells[:, [0, 2, 1]], cells)
    area = np.abs(area)
    angles = np.degrees(interior_angles(x, cells))
    if (
        area.min() <= 0
        or abs(area.sum() - 1.0) > 1e-12
        or angles.max() >= 90.0
        or not np.all((steiner > 0) & (steiner < 1))
    ):
        raise RuntimeError(f"invalid acute stencil for corner mask {mask}")  # pragma: no cover
    return x, cells


def _build_stencils() -> list[tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], int]]:
    """The 16 stencils, indexed by corner mask: ``(points, triangles, num_boundary_points)``.

    Points are in unit-square coordinates, boundary points first (in the order of
    :func:`_boundary_points`); triangles are counter-clockwise.
    """
    base = {0: (_MASK0_POINTS[8:], _MASK0_CELLS), 15: _mask15(), **_DESIGNED}
    stencils: list = [None] * 16
    for b, (steiner, cells) in base.items():
        x, cells = _check_stencil(b, steiner, cells)
        nb = len(_boundary_points(b))
        for r in range(4):
            m = _rotate_mask(b, r)
            if stencils[m] is not None:
                continue
            y = x.copy()
            for _ in range(r):  # quarter turn about the centre: (x, y) -> (1 - y, x)
                y = np.column_stack([1.0 - y[:, 1], y[:, 0]])
            # Reorder the boundary points into the canonical order for mask m.
            q = np.rint(4.0 * y[:nb]).astype(np.int64)
            canon = _boundary_points(m)
            lookup = {tuple(p): i for i, p in enumerate(canon)}
            perm = np.array([lookup[tuple(p)] for p in q])
            new_index = np.concatenate([perm, np.arange(nb, len(y))])
            pts = np.empty_like(y)
            pts[new_index] = y
            pts[:nb] = canon / 4.0  # exact
            stencils[m] = (pts, new_index[cells], nb)
    return stencils


def _reflect_mask(mask: int, axis: int) -> int:
    """Corner mask after the reflection ``x_axis -> 1 - x_axis`` of the unit square."""
    swap = ((0, 3), (1, 2)) if axis == 1 else ((0, 1), (3, 2))
    out = 0
    for a, b in swap:
        out |= (mask >> a & 1) << b | (mask >> b & 1) << a
    return out


def _mirror_stencils(
    stencils: list[tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], int]], axis: int
) -> list[tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], int]]:
    """The 16 stencils reflected by ``x_axis -> 1 - x_axis``, indexed by the corner mask of
    the leaf they tile (boundary points in its canonical order, triangles counter-clockwise):
    the leaves on one side of a mirror line take these, so that each leaf's triangles are
    the mirror images of its image leaf's (the boundary points of a mask are a symmetric
    set, so mirrored and unmirrored leaves still glue)."""
    out = []
    for m in range(16):
        pts, cells, nb = stencils[_reflect_mask(m, axis)]
        y = pts.copy()
        y[:, axis] = 1.0 - y[:, axis]
        q = np.rint(4.0 * y[:nb]).astype(np.int64)
        lookup = {tuple(p): i for i, p in enumerate(_boundary_points(m))}
        new_index = np.concatenate([[lookup[tuple(p)] for p in q], np.arange(nb, len(y))])
        moved = np.empty_like(y)
        moved[new_index] = y
        moved[:nb] = _boundary_points(m) / 4.0  # exact
        out.append((moved, new_index[cells][:, [0, 2, 1]], nb))
    return out


# ---------------------------------------------------------------------------------------------
# Quadtree
# ---------------------------------------------------------------------------------------------

_MAX_CELLS = 10_000_000  # cells of one level (about 1.5e8 triangles)
_CHUNK = 1 << 18  # leaves per block in the balance sweep


MAX_STRETCH = 1.1
"""Largest aspect ratio of the root cells of a box that is not a whole number of squares."""


def _parse_box(
    box: npt.ArrayLike, root_size: float | None = None
) -> tuple[float, float, float, float, float, float, int, int]:
    """``x0, y0, x1, y1, sx, sy, nx, ny`` of a box made of ``nx * ny`` equal root cells.

    Without ``root_size`` the cells are squares whose side is the box's shorter side (the box
    must be a whole number of them). With it, the cells are at most ``root_size`` wide and
    high and nearly square: ``max(sx, sy) / min(sx, sy) <= MAX_STRETCH`` (the stencils
    stretched by that much stay acute, see :data:`STRETCHED_ANGLE_RANGE`).
    """
    b = np.asarray(box, dtype=np.float64).reshape(2, 2)
    (x0, y0), (x1, y1) = b
    if not np.all(np.isfinite(b)) or x1 <= x0 or y1 <= y0:
        raise ValueError(f"need a finite box [[x0, y0], [x1, y1]] with x0 < x1, y0 < y1: {b}")
    w, h = x1 - x0, y1 - y0
    if root_size is None:
        side = min(w, h)
        nx, ny = round(w / side), round(h / side)
        if abs(nx * side - w) > 1e-9 * w or abs(ny * side - h) > 1e-9 * h:
            raise ValueError(
                f"box {b.tolist()} is not a whole number of equal squares "
                f"({w / side:g} x {h / side:g})"
            )
        sx = sy = side
    else:
        r = float(root_size)
        if not (r > 0 and np.isfinite(r)):
            raise ValueError(f"root_size must be positive and finite, got {root_size}")
        nx, ny = max(1, int(np.ceil(w / r))), max(1, int(np.ceil(h / r)))
        while max(w / nx, h / ny) / min(w / nx, h / ny) > MAX_STRETCH:
            if w / nx > h / ny:
                nx += 1
            else:
                ny += 1
        sx, sy = w / nx, h / ny
    return float(x0), float(y0), float(x1), float(y1), float(sx), float(sy), int(nx), int(ny)


Mirror = tuple[npt.ArrayLike, npt.ArrayLike]
"""A mirror line ``(point, normal)``."""


def mirror_axis(mirror: Mirror, gdim: int) -> tuple[int, float]:
    """The axis of an axis-aligned mirror and the mirror's coordinate on it.

    Parameters
    ----------
    mirror
        ``(point, normal)``: a line (plane) through ``point`` with normal ``normal``.
    gdim
        The dimension of the points.

    Returns
    -------
    The axis ``i`` the normal lies along and ``point[i]``.

    Raises
    ------
    ValueError
        For a normal along no coordinate axis, or input that is not ``gdim`` finite
        numbers each (:func:`~dolfinx_universal.core.arrays.mirror_line`).
    """
    point, normal = mirror_line(mirror, gdim)
    axes = np.flatnonzero(normal != 0.0)
    if len(axes) != 1:
        raise ValueError(
            f"the background's mirror must be normal to a coordinate axis, got normal {normal}"
        )
    return int(axes[0]), float(point[axes[0]])


def _mirror_breaks(
    box: npt.ArrayLike, root_size: float | None, mirror: Mirror
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], int, int]:
    """Root cells of a box symmetric about an axis-aligned mirror line near it.

    Returns the cells' boundaries along x and y, the mirror's axis and the index of the
    boundary on the line.

    The line is a boundary of root cells; the rows (columns for a vertical line) on its
    shorter side are mirrored on the longer side, as many of them as leave the rest of the
    longer side to rows within :data:`MAX_STRETCH` of square; the root cells are at most
    ``root_size`` (default: the box's shorter side), halved until this is possible.
    """
    b = np.asarray(box, dtype=np.float64).reshape(2, 2)
    if not np.all(np.isfinite(b)) or b[1, 0] <= b[0, 0] or b[1, 1] <= b[0, 1]:
        raise ValueError(f"need a finite box [[x0, y0], [x1, y1]] with x0 < x1, y0 < y1: {b}")
    axis, a = mirror_axis(mirror, 2)
    lo, hi = float(b[0, axis]), float(b[1, axis])
    if not lo < a < hi:
        raise ValueError(f"the mirror line {axis and 'y' or 'x'} = {a} does not cross the box")
    width = float(b[1, 1 - axis] - b[0, 1 - axis])
    s = min(width, hi - lo) if root_size is None else float(root_size)
    short, long = sorted((a - lo, hi - a))
    slack = 1.0 + 1e-9  # ratios such as 0.11 / 0.1 computed within rounding of 1.1
    for _ in range(60):
        n_s = max(1, int(np.ceil(short / s - 1e-9)))
        t = short / n_s
        n_t = max(1, round(width / t))
        st = width / n_t
        rows = None
        if max(st, t) / min(st, t) <= MAX_STRETCH * slack:
            for k in range(n_s, 0, -1):  # mirrored rows on the longer side
                rest = long - k * t
                if rest <= 1e-9 * long:
                    rows = (k, 0, 0.0)
                    break
                m_lo = max(1, int(np.ceil(rest / (MAX_STRETCH * st) - 1e-9)))
                m_hi = int(np.floor(rest * MAX_STRETCH / st + 1e-9))
                if m_lo <= m_hi:
                    m = min(max(round(rest / st), m_lo), m_hi)
                    rows = (k, m, rest / m)
                    break
        if rows is not None:
            k, m, u = rows
            sign = 1.0 if a - lo <= hi - a else -1.0  # the shorter side: below / above a
            near = a - sign * t * np.arange(n_s + 1)
            far = np.concatenate(
                [a + sign * t * np.arange(k + 1), a + sign * (k * t + u * np.arange(1, m + 1))]
            )
            side = (
                np.concatenate([near[::-1], far[1:]])
                if sign > 0
                else np.concatenate([far[::-1], near[1:]])
            )
            side[0], side[-1] = lo, hi
            k_axis = int(np.flatnonzero(side == a)[0])
            other = b[0, 1 - axis] + st * np.arange(n_t + 1)
            other[0], other[-1] = b[0, 1 - axis], b[1, 1 - axis]
            bx, by = (side, other) if axis == 0 else (other, side)
            return bx, by, axis, k_axis
        s /= 2.0
    raise ValueError(
        f"no root cells of {b.tolist()} are symmetric about {mirror}"
    )  # pragma: no cover


def _target_size(
    size: SizeLike, side: float, min_size: float | None, max_size: float | None
) -> Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]]:
    """The clipped target size ``h(x) = clip(size(x), min_size, max_size)``."""
    lo = side * 2.0**-20 if min_size is None else float(min_size)
    hi = np.inf if max_size is None else float(max_size)
    if not lo > 0 or hi < lo:
        raise ValueError(f"need 0 < min_size <= max_size, got {min_size}, {max_size}")

    if callable(size):

        def h(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
            v = np.asarray(size(x), dtype=np.float64)
            v = np.broadcast_to(v.reshape(-1) if v.size == len(x) else v, (len(x),))
            if not np.all(v > 0):  # also catches NaN
                raise ValueError("size function must return positive values")
            return np.clip(v, lo, hi)

    else:
        value = float(size)
        if not value > 0 or not np.isfinite(value):
            raise ValueError(f"size must be positive and finite, got {size}")
        value = min(max(value, lo), hi)

        def h(x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
            return np.full(len(x), value)

    return h


def _split(keys: np.ndarray, ny_l: int) -> tuple[np.ndarray, np.ndarray]:
    return keys // ny_l, keys % ny_l


def _children(keys: np.ndarray, ny_l: int) -> np.ndarray:
    """Sorted keys at level l + 1 of the four children of each cell (keys at level l)."""
    i, j = _split(keys, ny_l)
    ny_c = 2 * ny_l
    ci = (2 * i)[:, None] + np.array([0, 0, 1, 1])
    cj = (2 * j)[:, None] + np.array([0, 1, 0, 1])
    return np.sort((ci * ny_c + cj).ravel())


def _refine(
    h: Callable,
    x0: float,
    y0: float,
    sx: float,
    sy: float,
    nx: int,
    ny: int,
    comm: MPI.Comm | None = None,
    breaks: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[np.ndarray]:
    """Top-down refinement by size: sorted keys of the split cells, per level.

    With ``breaks`` (the root cells' boundaries along x and y), the root cells are those
    (``x0, y0, sx, sy`` in root units: 0, 0, 1, 1) and a cell's points and side are mapped
    through them.

    With ``comm`` (several ranks), each rank samples ``h`` on a contiguous slice of each
    level's cells and the split decisions are gathered: the same tree on every rank, each
    point sampled once (``h`` is pointwise), an exception in ``h`` raised on every rank.
    """
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    keys = (i * ny + j).ravel().astype(np.int64)
    refined: list[np.ndarray] = []
    level = 0
    offsets = np.array([[a, b] for a in (0.0, 0.5, 1.0) for b in (0.0, 0.5, 1.0)])
    while len(keys):
        if len(keys) > _MAX_CELLS:
            raise ValueError("the size function asks for more than 1e7 quadtree cells on one level")
        ny_l = ny << level
        s = np.array([sx, sy]) / 2.0**level

        def splits(
            k: np.ndarray, ny_l: int = ny_l, s: np.ndarray = s, level: int = level
        ) -> np.ndarray:
            ci, cj = _split(k, ny_l)
            corner = np.column_stack([x0 + ci * s[0], y0 + cj * s[1]])
            pts = (corner[:, None, :] + s * offsets[None]).reshape(-1, 2)
            if breaks is None:
                hmin = h(pts).reshape(len(k), len(offsets)).min(axis=1)
                return EDGE_FACTOR * s.max() > hmin
            # In root units the samples are exact lattice points (bitwise equal where two or
            # four cells share one): the size at each distinct one (about 4 of the 9 a cell).
            first, inverse = distinct_rows(pts)
            values = np.asarray(h(_through(breaks, pts[first])))
            values = values if inverse is None else values[inverse]
            hmin = values.reshape(len(k), len(offsets)).min(axis=1)
            side = np.maximum(np.diff(breaks[0])[ci >> level], np.diff(breaks[1])[cj >> level]) * (
                0.5**level
            )
            return EDGE_FACTOR * side > hmin

        if comm is None or comm.size == 1:
            split = keys[splits(keys)]
        else:
            a, b = (len(keys) * r // comm.size for r in (comm.rank, comm.rank + 1))
            try:
                mine, error = splits(keys[a:b]), None
            except Exception as e:  # a user size function failing on some ranks' points
                mine, error = np.zeros(b - a, dtype=bool), f"{type(e).__name__}: {e}"
            gathered = comm.allgather((mine, error))
            errors = [e for _, e in gathered if e is not None]
            if errors:
                raise ValueError(f"the size function failed: {errors[0]}")
            split = keys[np.concatenate([m for m, _ in gathered])]
        refined.append(split)
        keys = _children(split, ny_l)
        level += 1
    while refined and not len(refined[-1]):
        refined.pop()
    return refined


_NEIGHBOURS = np.array([[a, b] for a in (-1, 0, 1) for b in (-1, 0, 1) if a or b])


def _balance(refined: list[np.ndarray], nx: int, ny: int) -> list[np.ndarray]:
    """Corner-balance the quadtree: leaves sharing a vertex differ by at most one level.

    One sweep from the finest level to the coarsest: a leaf at level l requires each of its
    eight neighbouring cells at level l to lie in a node of level >= l - 1, i.e. the
    grandparent (level l - 2) of the neighbour must be split. Requirements only create leaves
    at coarser levels, which are processed later in the sweep; ancestors of split cells are
    split as well (closure), level by level.
    """
    refined = [r.copy() for r in refined] + [np.empty(0, dtype=np.int64)]
    for level in range(len(refined) - 1, 0, -1):
        ny_l, ny_p = ny << level, ny << (level - 1)
        pi, pj = _split(refined[level], ny_l)
        refined[level - 1] = np.union1d(refined[level - 1], (pi // 2) * ny_p + pj // 2)
        if level < 2:
            continue
        nodes = _children(refined[level - 1], ny_p)
        leaves = np.setdiff1d(nodes, refined[level], assume_unique=True)
        ny_g = ny << (level - 2)
        grand = []
        for c in range(0, len(leaves), _CHUNK):  # bounded temporaries (8 neighbours a leaf)
            i, j = _split(leaves[c : c + _CHUNK], ny_l)
            ni = (i[:, None] + _NEIGHBOURS[:, 0]).ravel()
            nj = (j[:, None] + _NEIGHBOURS[:, 1]).ravel()
            inside = (ni >= 0) & (nj >= 0) & (ni < nx << level) & (nj < ny_l)
            grand.append(np.unique((ni[inside] // 4) * ny_g + nj[inside] // 4))
        refined[level - 2] = np.union1d(refined[level - 2], np.concatenate(grand or [leaves[:0]]))
    while len(refined) > 0 and not len(refined[-1]):
        refined.pop()
    return refined


def _symmetrized(
    refined: list[np.ndarray], nx: int, ny: int, axis: int, k: int, band: int
) -> list[np.ndarray]:
    """The split cells with the mirror images of those in the ``band`` root rows (columns
    for ``axis`` 0) on each side of the line at root boundary ``k``."""
    out = []
    for level, keys in enumerate(refined):
        ny_l = ny << level
        i, j = _split(keys, ny_l)
        c = (i, j)[axis]
        inside = (c >= (k - band) << level) & (c < (k + band) << level)
        image = ((2 * k) << level) - 1 - c[inside]
        mi, mj = (image, j[inside]) if axis == 0 else (i[inside], image)
        out.append(np.union1d(keys, mi * ny_l + mj))
    return out


def _leaves(refined: list[np.ndarray], nx: int, ny: int) -> list[np.ndarray]:
    """Sorted keys of the leaves, per level (levels 0 .. len(refined))."""
    out = []
    nodes = np.arange(nx * ny, dtype=np.int64)
    for level in range(len(refined) + 1):
        split = refined[level] if level < len(refined) else np.empty(0, dtype=np.int64)
        out.append(np.setdiff1d(nodes, split, assume_unique=True))
        nodes = _children(split, ny << level)
    return out


def _leaf_corner_masks(
    leaves: np.ndarray, refined: np.ndarray, level: int, nx: int, ny: int
) -> np.ndarray:
    """Fine-corner masks of the leaves at one level.

    A corner of a leaf at level l is fine when one of the four level-l cells around it is
    split, i.e. when a smaller leaf (level l + 1, by corner balance) touches it. Consistency
    of the boundary points: a side of length s between two leaves of level l carries a point
    at s/4 from an end exactly when that end is fine for both (same criterion); a side half
    of length s between a level-l leaf and a level-(l-1) leaf carries the coarse leaf's
    quarter point at its middle, and no point at s/4 from its ends, because such a point
    would need a level-(l+1) leaf at a vertex of the level-(l-1) leaf.
    """
    ny_l = ny << level
    nyv = ny_l + 1  # vertex keys at this level: vx * (ny_l + 1) + vy
    ri, rj = _split(refined, ny_l)
    fine = np.unique(np.concatenate([(ri + a) * nyv + rj + b for a in (0, 1) for b in (0, 1)]))
    i, j = _split(leaves, ny_l)
    mask = np.zeros(len(leaves), dtype=np.int64)
    if not len(fine):
        return mask
    for c, (a, b) in enumerate(((0, 0), (1, 0), (1, 1), (0, 1))):
        v = (i + a) * nyv + j + b
        pos = np.searchsorted(fine, v)
        hit = (pos < len(fine)) & (fine[np.minimum(pos, len(fine) - 1)] == v)
        mask |= hit.astype(np.int64) << c
    return mask


# ---------------------------------------------------------------------------------------------
# Assembly
# ---------------------------------------------------------------------------------------------


class _Tree(NamedTuple):
    """A balanced quadtree over the root cells of a box, with its lattice (see below)."""

    x0: float
    y0: float
    x1: float
    y1: float
    nx: int
    ny: int
    refined: list[np.ndarray]  # sorted keys of the split cells, per level
    leaves: list[np.ndarray]  # sorted keys of the leaves, per level
    shift: int  # lattice: a quarter of the finest leaf side, 2**-shift of a root side
    nyq: int  # lattice point (X, Y) has key X * nyq + Y
    unit: npt.NDArray[np.float64]  # lattice spacing in x and y
    breaks: tuple[np.ndarray, np.ndarray] | None = None  # root boundaries (root units above)
    mirror: tuple[int, int] | None = None  # mirrored leaves: root index below (axis, k)


def _through(breaks: tuple[np.ndarray, np.ndarray], p: np.ndarray) -> npt.NDArray[np.float64]:
    """Points ``(n, 2)`` in root units mapped through the root cells' boundaries (affine on
    each root cell)."""
    bx, by = breaks
    return np.column_stack(
        [
            np.interp(p[:, 0], np.arange(len(bx), dtype=np.float64), bx),
            np.interp(p[:, 1], np.arange(len(by), dtype=np.float64), by),
        ]
    )


def _tree(
    box: Sequence[Sequence[float]] | npt.ArrayLike,
    size: SizeLike,
    min_size: float | None,
    max_size: float | None,
    root_size: float | None,
    comm: MPI.Comm | None = None,
    mirror: Mirror | None = None,
) -> _Tree:
    """Refine by size and corner-balance the quadtree of a box (keys only, no triangles);
    with ``comm``, the size is sampled in parallel (:func:`_refine`); with ``mirror``, on
    the root cells of :func:`_mirror_breaks` (the tree in root units)."""
    if mirror is None:
        x0, y0, x1, y1, sx, sy, nx, ny = _parse_box(box, root_size)
        h = _target_size(size, min(sx, sy), min_size, max_size)
        refined = _balance(_refine(h, x0, y0, sx, sy, nx, ny, comm), nx, ny)
        breaks, flip = None, None
    else:
        bx, by, axis, k = _mirror_breaks(box, root_size, mirror)
        nx, ny = len(bx) - 1, len(by) - 1
        x0, y0, x1, y1, sx, sy = 0.0, 0.0, float(nx), float(ny), 1.0, 1.0
        breaks, flip = (bx, by), (axis, k)
        side = min(np.diff(bx).min(), np.diff(by).min())
        h = _target_size(size, side, min_size, max_size)
        refined = _refine(h, x0, y0, sx, sy, nx, ny, comm, breaks)
        # Split a cell where its image is split (rounding of the sizes at the two, and the
        # balance with the rows beyond, could split only one), until the balanced tree is
        # symmetric: in the mirrored rows, and, by row index, in the rows beyond them
        # (their heights differ, but their leaves' corners, and so the stencils of the
        # mirrored rows' leaves, are then symmetric too).
        pairs = min(k, (nx if axis == 0 else ny) - k)
        while True:
            refined = _balance(refined, nx, ny)
            mirrored = _symmetrized(refined, nx, ny, axis, k, pairs)
            if all(len(a) == len(b) for a, b in zip(refined, mirrored, strict=True)):
                break
            refined = mirrored
    leaves = _leaves(refined, nx, ny)
    shift = len(leaves) + 1  # lattice: quarter of the finest leaf side
    nyq = (ny << shift) + 1
    unit = np.array([sx, sy]) / 2.0**shift
    return _Tree(x0, y0, x1, y1, nx, ny, refined, leaves, shift, nyq, unit, breaks, flip)


def _stencil_groups(
    t: _Tree, leaves: list[np.ndarray]
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Tile ``leaves`` (a subset of ``t.leaves``, per level) with their stencils.

    Returns, per (level, corner mask) group: the lattice keys of the leaves' boundary points
    ``(n, nb)``, their Steiner points ``(n, ns, 2)`` and the stencil's triangles ``(t, 3)``
    (indices into boundary points, then Steiner points).
    """
    fine_level = len(t.leaves) - 1
    groups = []
    for level, keys in enumerate(leaves):
        if not len(keys):
            continue
        split = t.refined[level] if level < len(t.refined) else np.empty(0, dtype=np.int64)
        masks = _leaf_corner_masks(keys, split, level, t.nx, t.ny)
        i, j = _split(keys, t.ny << level)
        step = 1 << (fine_level - level)  # a quarter of this leaf's side, in lattice units
        # Leaves on the lower side of a mirror line take the mirrored stencils.
        flipped = np.zeros(len(keys), dtype=bool)
        if t.mirror is not None:
            axis, k = t.mirror
            flipped = ((i, j)[axis] >> level) < k
        for m in np.unique(masks):
            for flip in (False, True):
                sel = (masks == m) & (flipped == flip)
                if not sel.any():
                    continue
                pts, tris, nb = (_MIRRORED[t.mirror[0]] if flip else _STENCILS)[m]  # type: ignore[index]
                ox, oy = (i[sel] << (t.shift - level)), (j[sel] << (t.shift - level))
                q = np.rint(4.0 * pts[:nb]).astype(np.int64) * step
                bkeys = (ox[:, None] + q[:, 0]) * t.nyq + oy[:, None] + q[:, 1]
                origin = np.column_stack([t.x0 + ox * t.unit[0], t.y0 + oy * t.unit[1]])
                steiner = origin[:, None, :] + (4 * step * t.unit) * pts[None, nb:]
                if t.breaks is not None:
                    steiner = _through(t.breaks, steiner.reshape(-1, 2)).reshape(steiner.shape)
                groups.append((bkeys, steiner, tris))
    return groups


def _lattice_coordinates(t: _Tree, keys: np.ndarray) -> npt.NDArray[np.float64]:
    """Coordinates of lattice points; points on the box's sides lie exactly on them."""
    X, Y = keys // t.nyq, keys % t.nyq
    xl = np.column_stack([t.x0 + X * t.unit[0], t.y0 + Y * t.unit[1]])
    if t.breaks is not None:  # (the box's sides are exact: the ends of the breaks)
        return _through(t.breaks, xl)
    xl[X == 0, 0], xl[X == t.nx << t.shift, 0] = t.x0, t.x1  # the box, exactly
    xl[Y == 0, 1], xl[Y == t.ny << t.shift, 1] = t.y0, t.y1
    return xl


def _assemble(
    groups: list[tuple[np.ndarray, np.ndarray, np.ndarray]], lattice_index: np.ndarray, soff: int
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Cells of the groups: boundary points numbered by ``lattice_index`` (flat, in group
    order), Steiner points numbered consecutively from ``soff``. Returns cells and the
    Steiner coordinates, per group."""
    coords, cells = [], []
    koff = 0
    for bkeys, steiner, tris in groups:
        n, nb = bkeys.shape
        ns = steiner.shape[1]
        table = np.empty((n, nb + ns), dtype=np.int64)
        table[:, :nb] = lattice_index[koff : koff + n * nb].reshape(n, nb)
        table[:, nb:] = soff + np.arange(n * ns).reshape(n, ns)
        cells.append(table[:, tris].reshape(-1, 3))
        coords.append(steiner.reshape(-1, 2))
        koff += n * nb
        soff += n * ns
    return cells, coords


def _leaf_ranks(t: _Tree, nparts: int) -> list[np.ndarray]:
    """Rank of every leaf, per level: contiguous runs of equal triangle counts along a
    space-filling order (root cells in key order, Morton order inside each root)."""
    fine = len(t.leaves) - 1
    root_bits = max(int(t.nx * t.ny - 1).bit_length(), 1)
    packed = 2 * fine + root_bits <= 62  # (root, Morton) fits one int64 sort key
    order_keys, roots, weights = [], [], []
    for lv, k in enumerate(t.leaves):
        i, j = k // (t.ny << lv), k % (t.ny << lv)
        root = (i >> lv) * t.ny + (j >> lv)
        fi = (i - ((i >> lv) << lv)) << (fine - lv)  # finest-level corner inside the root
        fj = (j - ((j >> lv) << lv)) << (fine - lv)
        morton = np.zeros(len(k), dtype=np.int64)
        for b in range(fine):
            morton |= ((fi >> b) & 1) << (2 * b + 1) | ((fj >> b) & 1) << (2 * b)
        order_keys.append((root << (2 * fine)) | morton if packed else morton)
        roots.append(root if not packed else root[:0])
        split = t.refined[lv] if lv < len(t.refined) else k[:0]
        weights.append(_NUM_TRIANGLES[_leaf_corner_masks(k, split, lv, t.nx, t.ny)])
    if packed:
        order = np.argsort(np.concatenate(order_keys), kind="stable")
    else:
        order = np.lexsort((np.concatenate(order_keys), np.concatenate(roots)))
    del order_keys, roots
    w = np.concatenate(weights)[order]
    start = np.cumsum(w) - w
    part = np.empty(len(w), dtype=np.int32)
    part[order] = start * nparts // max(int(w.sum()), 1)
    bounds = np.cumsum([0] + [len(k) for k in t.leaves])
    return [part[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


def _lattice_owners(t: _Tree, ranks: list[np.ndarray], keys: np.ndarray) -> np.ndarray:
    """Rank owning each lattice point: the rank of the leaf just above and to the right of it
    (below or to the left on the box's top and right sides). That leaf has the point among
    its boundary points (the corner, or a point on a side it shares with any other leaf
    touching the point)."""
    X = np.minimum(keys // t.nyq, (t.nx << t.shift) - 1)
    Y = np.minimum(keys % t.nyq, (t.ny << t.shift) - 1)
    owner = np.full(len(keys), -1, dtype=np.int64)
    for lv, lk in enumerate(t.leaves):
        if not len(lk):
            continue
        k = (X >> (t.shift - lv)) * (t.ny << lv) + (Y >> (t.shift - lv))
        pos = np.minimum(np.searchsorted(lk, k), len(lk) - 1)
        hit = lk[pos] == k
        owner[hit] = ranks[lv][pos[hit]]
    return owner


def _distributed_part(
    comm: MPI.Comm, t: _Tree
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """This rank's block of vertices and its cells (global vertex numbers) of the
    triangulation of the tree ``t`` (the same tree on every rank).

    Rank ``r`` tiles its leaves (:func:`_leaf_ranks`); its block of vertices holds the
    lattice points it owns (:func:`_lattice_owners`), sorted by key, then its Steiner points.
    The numbers of lattice points owned elsewhere are asked from their owners.
    """
    ranks = _leaf_ranks(t, comm.size)
    mine = [lk[r == comm.rank] for lk, r in zip(t.leaves, ranks, strict=True)]
    groups = _stencil_groups(t, mine)
    all_keys = np.concatenate([g[0].ravel() for g in groups] or [np.empty(0, np.int64)])
    lattice, inverse = np.unique(all_keys, return_inverse=True)
    owner = _lattice_owners(t, ranks, lattice)
    own = owner == comm.rank
    owned = lattice[own]
    num_steiner = sum(g[1].shape[0] * g[1].shape[1] for g in groups)
    offset = int(sum(comm.allgather(len(owned) + num_steiner)[: comm.rank]))
    index = np.empty(len(lattice), dtype=np.int64)
    index[own] = offset + np.arange(len(owned))
    # Ask the owners for the numbers of the other lattice points.
    order = np.argsort(owner, kind="stable")
    bounds = np.searchsorted(owner[order], np.arange(comm.size + 1))
    asked = [lattice[order[a:b]] for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    asked[comm.rank] = np.empty(0, dtype=np.int64)
    questions = comm.alltoall(asked)
    answers = comm.alltoall([offset + np.searchsorted(owned, q) for q in questions])
    for q, a, b in zip(range(comm.size), bounds[:-1], bounds[1:], strict=True):
        if q != comm.rank:
            index[order[a:b]] = answers[q]
    cells, coords = _assemble(groups, index[inverse.ravel()], offset + len(owned))
    x = np.vstack([_lattice_coordinates(t, owned), *coords])
    return x, np.concatenate(cells or [np.empty((0, 3), np.int64)]).astype(np.int64)


def acute_quadtree_triangulation(
    box: Sequence[Sequence[float]] | npt.ArrayLike,
    size: SizeLike,
    min_size: float | None = None,
    max_size: float | None = None,
    root_size: float | None = None,
    mirror: Mirror | None = None,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Graded triangulation of a box by acute triangles, from a balanced quadtree.

    The box is covered by equal root squares. A square of side ``s`` is split into four
    while ``EDGE_FACTOR * s > h`` (:data:`EDGE_FACTOR` ~ 0.53 is the longest stencil edge
    relative to the leaf side), ``h`` being the clipped target size
    ``clip(size, min_size, max_size)`` minimised over the square's centre, corners and side
    midpoints; so no edge is longer than ``h`` there. A leaf is at least half as large as
    this rule allows (sampling ``h`` on its parent), unless it was split to balance the tree. The
    quadtree is then corner-balanced (leaves sharing a vertex, hence also leaves sharing an
    edge, differ by at most one level; a sweep over levels, vectorised per level) and every
    leaf is tiled with one of 16 acute stencils (see the module notes), chosen by which of its
    corners touch a smaller leaf.

    All angles lie in :data:`STENCIL_ANGLE_RANGE` (degrees), whatever the size function.
    Only those nine samples per square are seen, so features of the size function narrower
    than the squares they fall in can be missed. Where the size grows faster than the balance
    allows (leaf sides at most double from one leaf to the next), the mesh is finer than asked.

    Parameters
    ----------
    box
        ``[[x0, y0], [x1, y1]]``: a square, or a rectangle made of a whole number of equal
        squares (e.g. 2 x 1). Its boundary is exactly the boundary of the triangulation.
    size
        Target edge length: a positive float, or a vectorised callable mapping points
        ``(n, 2)`` to sizes ``(n,)``.
    min_size
        Lower clip of the size (default ``side * 2**-20``, ``side`` = root square side).
    max_size
        Upper clip of the size (default: none; the root squares are the coarsest leaves).
    root_size
        Largest side of the root cells. Given, the box may have any shape: it is divided
        into nearly square root cells (aspect ratio at most :data:`MAX_STRETCH`; the
        stencils are stretched with them and keep their angles in
        :data:`STRETCHED_ANGLE_RANGE`).
    mirror
        A line ``(point, normal)`` normal to a coordinate axis that crosses the box: the
        triangulation is made symmetric about it where the box is. The line is a side of
        root cells, the rows of root cells (columns, for a vertical line) on its shorter
        side are mirrored on the other, as many as leave the rest of the box to rows within
        :data:`MAX_STRETCH` of square (root cells at most ``root_size``, smaller where that
        needs it: a channel of height 0.41 about y = 0.2 gets rows 0.1, 0.1 | 0.1, 0.11),
        and the leaves below the line (left of it) are tiled with the mirror images of the
        stencils. Where ``size`` is symmetric too, the mesh of the mirrored rows is the
        mirror image of itself, up to rounding.

    Returns
    -------
    x
        Vertex coordinates ``(num_vertices, 2)``; no duplicates.
    cells
        Counter-clockwise triangles ``(num_cells, 3)``.
    """
    t = _tree(box, size, min_size, max_size, root_size, mirror=mirror)
    groups = _stencil_groups(t, t.leaves)
    all_keys = np.concatenate([g[0].ravel() for g in groups])
    lattice, inverse = np.unique(all_keys, return_inverse=True)
    cells, coords = _assemble(groups, inverse.ravel(), len(lattice))
    return np.vstack([_lattice_coordinates(t, lattice), *coords]), np.concatenate(cells).astype(
        np.int64
    )


def graded_mesh(
    comm: MPI.Comm,
    box: Sequence[Sequence[float]] | npt.ArrayLike,
    size: SizeLike,
    min_size: float | None = None,
    max_size: float | None = None,
    root_size: float | None = None,
    mirror: Mirror | None = None,
) -> dmesh.Mesh:
    """Distributed graded acute mesh of a box (see :func:`acute_quadtree_triangulation`).

    Built in parallel, the same mesh on any number of ranks (up to numbering), with
    shared-facet ghosts. Every rank holds the quadtree (keys of the split cells and leaves
    only), which makes the 2:1 balance and the stencil choice exactly those of the serial
    build; the tree is small beside the triangulation (a leaf carries 14 to 56 triangles).
    The size is sampled in parallel: each rank calls ``size`` on a slice of each level's
    cells (so ``size`` must be pointwise, as its values at given points are) and the split
    decisions are gathered; an exception in ``size`` is raised on every rank (as a
    ``ValueError``). The leaves are then split into contiguous runs of equal triangle
    counts along a space-filling order (root cells in key order, Morton order in a root);
    each rank tiles only its own leaves, owns their triangles (no graph partitioning,
    :func:`~dolfinx_universal.backgrounds.lattice_tri.layout_partitioner`) and numbers the vertices
    it
    owns: lattice points by a fixed rule (the rank of the leaf above and to the right of the
    point), asked from their owner by the other ranks, and its Steiner points. Vertex
    coordinates are bitwise those of :func:`acute_quadtree_triangulation`; on one rank the
    mesh is built from its arrays directly.

    Parameters
    ----------
    comm
        Communicator of the mesh.
    box, size, min_size, max_size, root_size, mirror
        As in :func:`acute_quadtree_triangulation`.

    Returns
    -------
    A DOLFINx mesh with degree-1 geometry.
    """
    if comm.size == 1:
        x, cells = acute_quadtree_triangulation(box, size, min_size, max_size, root_size, mirror)
        return create_mesh(comm, cells, x)
    t = _tree(box, size, min_size, max_size, root_size, comm, mirror)
    x, cells = _distributed_part(comm, t)
    return create_mesh(comm, cells, x, layout_partitioner())


def local_size(x: npt.ArrayLike, cells: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Per-vertex mesh size: the largest diameter (longest edge) of the incident triangles.

    Parameters
    ----------
    x
        Vertex coordinates ``(num_vertices, gdim)``.
    cells
        Triangles ``(num_cells, 3)``.

    Returns
    -------
    Sizes ``(num_vertices,)``; zero at vertices in no cell.
    """
    x = np.asarray(x, dtype=np.float64)
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    diam = cell_diameters(x, cells)
    out = np.zeros(len(x))
    for k in range(3):
        np.maximum.at(out, cells[:, k], diam)
    return out


_STENCILS = _build_stencils()
_MIRRORED = [_mirror_stencils(_STENCILS, axis) for axis in (0, 1)]
_NUM_TRIANGLES = np.array([len(t) for _, t, _ in _STENCILS], dtype=np.int64)
_STRETCH = (np.array([MAX_STRETCH, 1.0]), np.array([1.0, MAX_STRETCH]))
_ALL_ANGLES = np.concatenate([np.degrees(interior_angles(p, t)).ravel() for p, t, _ in _STENCILS])
_ALL_EDGES = np.concatenate([edge_lengths(p, t).ravel() for p, t, _ in _STENCILS])
#: Smallest and largest angle (degrees) of any triangle of any stencil, hence of any mesh
#: built here.
STENCIL_ANGLE_RANGE: tuple[float, float] = (float(_ALL_ANGLES.min()), float(_ALL_ANGLES.max()))
#: Longest stencil edge relative to the leaf side: leaves of side ``s`` are split while
#: ``EDGE_FACTOR * s`` exceeds the target size, so that no edge is longer than the target.
EDGE_FACTOR: float = float(_ALL_EDGES.max())
#: Shortest stencil edge relative to the leaf side.
_EDGE_MIN: float = float(_ALL_EDGES.min())

#: Smallest and largest angle (degrees) of the stencils stretched by up to
#: :data:`MAX_STRETCH` in x or y (root cells of boxes that are not whole squares).
_STRETCHED_ANGLES = [
    np.degrees(interior_angles(p * f, t)) for p, t, _ in _STENCILS for f in _STRETCH
]
STRETCHED_ANGLE_RANGE: tuple[float, float] = (
    float(min(a.min() for a in _STRETCHED_ANGLES)),
    float(max(a.max() for a in _STRETCHED_ANGLES)),
)
