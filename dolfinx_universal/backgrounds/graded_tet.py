"""Graded tetrahedral backgrounds: BCC tetrahedra on a 2:1-balanced octree.

The 3D counterpart of :mod:`~dolfinx_universal.backgrounds.graded_tri`: a box is covered by equal
root
cubes, refined as an octree until every leaf is at most the target size (sampled at its
centre and corners), the octree is corner-balanced (leaves that touch differ by at most one
level: across faces, edges and vertices), and every leaf is tetrahedralised by the graded
body-centred cubic (BCC) construction of Labelle & Shewchuk ("Isosurface stuffing", SIGGRAPH
2007). The vertices are the leaves' corners and centres (and face centres on the box
boundary); each leaf face ``F`` between the leaf's centre ``c`` and the other side gets:

* **equal neighbour** (centre ``c'``): the BCC octahedron ``c, c'`` over ``F``, split around
  the edge ``c c'``: the tetrahedron ``(c, c', a, b)`` for each edge ``ab`` of ``F``, or the
  two *bisected* BCC tetrahedra ``(c, c', a, m), (c, c', m, b)`` where a smaller leaf
  touching the edge put its midpoint ``m`` there. Dihedral angles 60-90 (BCC), 45-90
  (bisected).
* **four smaller neighbours** (``F`` has its centre ``f`` and its four edge midpoints): the
  pyramid ``c`` over ``F`` as 8 tetrahedra ``(c, f, a, m), (c, f, m, b)`` (BCC tetrahedra
  bisected twice: orthoschemes, dihedral angles 45, 60, 90).
* **larger neighbour** (``F`` is a quarter of the neighbour's face): the pyramid ``c`` over
  ``F`` split into two *half pyramids* by the diagonal through the larger face's centre (the
  one the larger leaf's orthoschemes have). Dihedral angles 45-120: the pyramid's lateral
  edges at the two corners off the diagonal keep the 120 degrees of the cube's centre
  pyramids. These are the only angles above 90; they occur only on the fine side of a level
  change.
* **box boundary**: the pyramid ``c`` over ``F`` from ``F``'s centre (4 tetrahedra, 8 with
  edge midpoints: halves of BCC tetrahedra, 45-90); the mesh's boundary is exactly the
  surface of the root cubes.

The corner balance leaves no edge midpoint on a face between leaves of different levels other
than those of the larger face, so the faces match from both sides (conforming by
construction). Every dihedral angle lies in :data:`DIHEDRAL_RANGE` ``= (45, 120)`` degrees,
in ``[60, 90]`` in the uniform parts (BCC of the leaf side ``s``: edges ``s`` and
``s sqrt(3)/2``) and in ``[45, 90]`` everywhere except the half pyramids.

The half pyramids' 120 degrees are those of the square pyramid from a cube's centre to a
face; splitting it otherwise does not help (a Steiner point at the small face's centre gives
bisected BCC tetrahedra, 45-90, on the small side but 125 degrees on the large side's; the
large cube refined around its face's quarter centres moves the problem to BCC tetrahedra
bisected across a short edge, 30-107). So level changes must stay out of the part of the
mesh that is cut or relaxed: :class:`BandSizeField` keeps a band around Gamma uniform.
A15, whose acute tetrahedra give better meshes near Gamma, does not grade this way: its
sites at sides ``a`` and ``2 a`` are not nested and its tetrahedra cross the faces of its
cubic cells (no flat boundary to meet an octree face), so an A15 band would need an
unstructured (Delaunay) layer to the octree, without an angle bound (Doran, UBC MSc 2013,
reports that his graded A15-based lattices did not beat graded BCC for isosurface stuffing).

Parallel build (:func:`graded_tet_mesh`): every rank holds the octree (keys of the split
cells and leaves per level: about a twelfth of the tetrahedra) and its per-leaf
classification; the leaves are split into contiguous runs of equal tetrahedron counts along
the Morton order. Each vertex is owned by the leaf that contains it when pushed by
``(+eps, +eps, +eps)`` (the last leaf along the box's upper faces) and numbered by (the
Morton position of its leaf, its place among the leaf's 27 half-side positions): rank ``r``
generates the vertices of its leaves (a contiguous block of the global numbering) and their
tetrahedra, ordered by leaf and by a fixed local index. The global arrays are bitwise those
of the serial :func:`graded_tetrahedralisation` on any number of ranks, with no
communication beyond the size samples.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import mesh as dmesh
from scipy.spatial import cKDTree

from dolfinx_universal.backgrounds.lattice_tri import create_mesh, layout_partitioner
from dolfinx_universal.core.arrays import Float, Int, kd_query

__all__ = [
    "DIHEDRAL_RANGE",
    "BandSizeField",
    "GradedOctree",
    "graded_octree",
    "graded_tet_mesh",
    "graded_tetrahedralisation",
]

SizeLike = float | Callable[[Float], npt.ArrayLike]

DIHEDRAL_RANGE: tuple[float, float] = (45.0, 120.0)
"""Smallest and largest dihedral angle (degrees) of any tetrahedron built here: BCC (60-90),
bisected BCC and orthoschemes (45-90), half pyramids at level changes (45-120)."""

_MAX_CELLS = 10_000_000  # octree cells of one level (about 1.2e8 tetrahedra)
_MAX_COORD = 1 << 21  # lattice coordinates per axis (21 bits: Morton keys in 63 bits)
_CHUNK = 1 << 17  # leaves per block in the balance sweep

# The 27 positions of a leaf, in half sides: p = 9 ox + 3 oy + oz.
_OFFSETS = np.array([(a, b, c) for a in range(3) for b in range(3) for c in range(3)])
_KIND = (_OFFSETS == 1).sum(axis=1)  # 0 corner, 1 edge midpoint, 2 face centre, 3 centre
_CENTRE = 13
_NEIGHBOURS = np.array(
    [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if a or b or c]
)

# Face-type codes.
_BOUNDARY, _COARSER, _SAME, _FINER = 0, 1, 2, 3


def _position(off: npt.ArrayLike) -> int:
    o = np.asarray(off)
    return int(9 * o[0] + 3 * o[1] + o[2])


def _face_positions(d: int, side: int) -> tuple[list[int], list[int], int]:
    """Positions of the corners (cyclic), edge midpoints (``m_t`` between corners ``t`` and
    ``t + 1``) and centre of the face of a leaf normal to axis ``d`` on side ``side``."""
    d1, d2 = (d + 1) % 3, (d + 2) % 3

    def pos(u: int, v: int) -> int:
        o = [0, 0, 0]
        o[d], o[d1], o[d2] = 2 * side, u, v
        return _position(o)

    cyc = [(0, 0), (2, 0), (2, 2), (0, 2)]
    corners = [pos(*c) for c in cyc]
    mids = [pos((cyc[t][0] + cyc[(t + 1) % 4][0]) // 2, (cyc[t][1] + cyc[(t + 1) % 4][1]) // 2)
            for t in range(4)]  # fmt: skip
    return corners, mids, pos(1, 1)


_FACES = [(d, s, *_face_positions(d, s)) for d in range(3) for s in range(2)]  # face id 2d + s


# ---------------------------------------------------------------------------------------------
# Size functions


def _check_box(box: npt.ArrayLike) -> Float:
    b = np.asarray(box, dtype=np.float64)
    if b.shape != (2, 3):
        raise ValueError(
            f"graded_tet_mesh needs a box [[xmin, ymin, zmin], [xmax, ymax, zmax]], got shape "
            f"{b.shape}"
        )
    if not np.all(np.isfinite(b)):
        raise ValueError(f"graded_tet_mesh needs a finite box, got {b.tolist()}")
    if np.any(b[1] <= b[0]):
        raise ValueError(f"empty box {b.tolist()}: need xmin < xmax, ymin < ymax and zmin < zmax")
    return b


def _size_function(size: SizeLike) -> Callable[[Float], Float]:
    if callable(size):

        def h(x: Float) -> Float:
            v = np.asarray(size(x), dtype=np.float64)
            v = np.broadcast_to(v.reshape(-1) if v.size == len(x) else v, (len(x),))
            if not np.all(v > 0):  # also catches NaN
                raise ValueError("size function must return positive values")
            return v

        return h
    value = float(size)
    if not (value > 0 and np.isfinite(value)):
        raise ValueError(f"size must be positive and finite, got {size}")
    return lambda x: np.full(len(x), value)


class BandSizeField:
    """A target size that is uniform in a band around sampled surfaces and grows away from it.

    ``h(x) = min(h_max, min_k (s_k + gradation max(d_k(x) - w_k, 0)))`` over the distinct
    sizes ``s_k`` of the sources: ``d_k`` the distance to the nearest source of size ``s_k``
    and ``w_k = band s_k + m_k`` the half-width of its band (``m_k``: the largest margin of
    those sources, their spacing, so that the band covers the surface between them). With
    ``gradation < 1`` every octree cell of side ``> s_k`` meeting the band is split
    (:func:`graded_tet_mesh` samples the size at the cells' centres and corners): the band is
    tiled by the leaves of side ``s_k`` (or smaller) only. One k-d tree query per distinct size.

    Parameters
    ----------
    points
        Source points ``(m, 3)`` (samples of the surface).
    sizes
        Size at each source ``(m,)`` (a few distinct values, e.g. octree leaf sides).
    h_max
        Largest size.
    band
        Band half-width in sizes.
    gradation
        Growth of the size per unit length beyond the band.
    margin
        Distance margin of each source ``(m,)`` or all (the sample spacing).
    normals, outer_band
        Optional: unit normals at the sources ``(m, 3)`` and the band half-width (in sizes)
        on the side they point to (the side is that of the nearest source); ``band`` is then
        the half-width on the other side.
    """

    def __init__(
        self,
        points: npt.ArrayLike,
        sizes: npt.ArrayLike,
        h_max: float,
        band: float = 5.0,
        gradation: float = 0.2,
        margin: float | npt.ArrayLike = 0.0,
        normals: npt.ArrayLike | None = None,
        outer_band: float | None = None,
    ) -> None:
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        s = np.broadcast_to(np.asarray(sizes, dtype=np.float64).reshape(-1), (len(p),))
        m = np.broadcast_to(np.asarray(margin, dtype=np.float64).reshape(-1), (len(p),))
        if (normals is None) != (outer_band is None):
            raise ValueError("give both normals and outer_band, or neither")
        self.normals = None if normals is None else np.asarray(normals, dtype=np.float64)
        if self.normals is not None:
            self.normals = self.normals.reshape(-1, 3)
            if len(self.normals) != len(p):
                raise ValueError(f"normals must have shape ({len(p)}, 3)")
        self.outer_band = band if outer_band is None else float(outer_band)
        if not (np.all(s > 0) and np.all(np.isfinite(s))):
            raise ValueError("sizes must be positive and finite")
        for name, v in (("h_max", h_max), ("gradation", gradation)):
            if not (float(v) > 0 and np.isfinite(float(v))):
                raise ValueError(f"{name} must be positive and finite, got {v}")
        if not (band >= 0 and self.outer_band >= 0 and np.all(m >= 0)):
            raise ValueError("bands and margins must be >= 0")
        self.h_max, self.band, self.gradation = float(h_max), float(band), float(gradation)
        self.points, self.sizes, self.margins = p, np.array(s), np.array(m)
        self._trees: list[tuple[float, float, Float, cKDTree]] | None = None

    def __getstate__(self) -> dict[str, object]:
        return {k: v for k, v in self.__dict__.items() if k != "_trees"} | {"_trees": None}

    def _groups(self) -> list[tuple[float, float, Float, cKDTree]]:
        if self._trees is None:
            keep = self.sizes < self.h_max
            p, s, m = self.points[keep], self.sizes[keep], self.margins[keep]
            n = self.normals[keep] if self.normals is not None else np.zeros_like(p)
            self._trees = [
                (float(v), float(m[s == v].max()), n[s == v], cKDTree(p[s == v]))
                for v in np.unique(s)
            ]
        return self._trees

    def __call__(self, x: npt.ArrayLike) -> Float:
        """Sizes ``(n,)`` at points ``x (n, 3)``."""
        x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
        h = np.full(len(x), self.h_max)
        g = self.gradation
        for s, margin, normals, tree in self._groups():
            w_in, w_out = self.band * s + margin, self.outer_band * s + margin
            reach = max(w_in, w_out) + (self.h_max - s) / g
            d, i = kd_query(tree, x, distance_upper_bound=reach)
            w = np.full(len(x), w_in)
            if self.normals is not None:  # the side of the nearest source's normal: outer
                hit = np.flatnonzero(i < tree.n)
                side = np.einsum("ij,ij->i", x[hit] - tree.data[i[hit]], normals[i[hit]])
                w[hit[side > 0]] = w_out
            np.minimum(h, s + g * np.maximum(d - w, 0.0), out=h)
        return h


# ---------------------------------------------------------------------------------------------
# Octree


class _Octree(NamedTuple):
    """A balanced octree over the root cubes of a box, with its lattice."""

    lo: Float  # (3,) corner of root cube (0, 0, 0)
    unit: float  # lattice unit: half the side of the finest possible leaf
    n: tuple[int, int, int]  # root cubes per axis
    depth: int  # D: leaves at levels 0 .. D; a leaf of level l has side 2^(D + 1 - l) units
    refined: list[Int]  # sorted keys of the split cells, per level 0 .. D - 1
    leaves: list[Int]  # sorted keys of the leaves, per level 0 .. D


def _unpack(keys: Int, n: tuple[int, int, int], level: int) -> tuple[Int, Int, Int]:
    ny, nz = n[1] << level, n[2] << level
    ij, k = np.divmod(keys, nz)
    i, j = np.divmod(ij, ny)
    return i, j, k


def _pack(i: Int, j: Int, k: Int, n: tuple[int, int, int], level: int) -> Int:
    return (i * (n[1] << level) + j) * (n[2] << level) + k


def _unique(a: Int) -> Int:
    """Sorted distinct values of ``a`` (by a sort: ``np.unique`` of NumPy 2.5 hashes, 100
    times slower on millions of int64 keys)."""
    s = np.sort(a.ravel())
    return s[np.concatenate([[True], s[1:] != s[:-1]])] if len(s) else s


def _children(keys: Int, n: tuple[int, int, int], level: int) -> Int:
    """Sorted keys at level ``level + 1`` of the 8 children of each cell."""
    i, j, k = _unpack(keys, n, level)
    o = _OFFSETS[np.all(_OFFSETS < 2, axis=1)]  # (8, 3) in {0, 1}
    c = _pack(
        (2 * i)[:, None] + o[:, 0], (2 * j)[:, None] + o[:, 1], (2 * k)[:, None] + o[:, 2],
        n, level + 1,
    )  # fmt: skip
    return np.sort(c.ravel())


def _parents(keys: Int, n: tuple[int, int, int], level: int, up: int = 1) -> Int:
    i, j, k = _unpack(keys, n, level)
    return _unique(_pack(i >> up, j >> up, k >> up, n, level - up))


def _root_layout(
    b: Float, max_size: float, min_size: float | None
) -> tuple[Float, float, tuple[int, int, int], int]:
    """Root cube side, grid and depth limit: the root side is ``max_size``, or the largest
    ``min_size 2^k <= max_size`` (the leaf sides are then ``min_size 2^k`` exactly)."""
    hi = float(max_size)
    if not (hi > 0 and np.isfinite(hi)):
        raise ValueError(f"max_size must be positive and finite, got {max_size}")
    if min_size is None:
        root, limit = hi, 20
    else:
        lo = float(min_size)
        if not (0 < lo <= hi):
            raise ValueError(f"need 0 < min_size <= max_size, got {min_size}, {max_size}")
        limit = int(np.floor(np.log2(hi / lo) + 1e-9))
        root = lo * 2.0**limit
    ext = b[1] - b[0]
    n = np.maximum(np.ceil(ext / root - 1e-9).astype(np.int64), 1)
    if np.any(n << 1 > _MAX_COORD):
        raise ValueError(f"the box {b.tolist()} needs too many root cubes of side {root:g}")
    lo_corner = 0.5 * (b[0] + b[1]) - 0.5 * root * n  # the root grid centred on the box
    while limit > 0 and int(n.max()) << (limit + 1) > _MAX_COORD:
        limit -= 1
    return lo_corner, root, (int(n[0]), int(n[1]), int(n[2])), limit


def _refine(
    h: Callable[[Float], Float],
    lo: Float,
    root: float,
    n: tuple[int, int, int],
    limit: int,
    comm: MPI.Comm | None,
) -> list[Int]:
    """Top-down refinement: a cell of side ``s`` is split while ``s`` exceeds the size at its
    centre or at one of its corners (each distinct point sampled once per level; with
    several ranks, each samples a slice and the values are gathered)."""
    keys = np.arange(n[0] * n[1] * n[2], dtype=np.int64)
    refined: list[Int] = []
    corner_off = _OFFSETS[np.all(_OFFSETS != 1, axis=1)] // 2  # (8, 3) in {0, 1}
    for level in range(limit):
        if len(keys) > _MAX_CELLS:
            raise ValueError(
                f"the size function asks for more than {_MAX_CELLS:.0e} octree cells on one level"
            )
        if not len(keys):
            break
        s = root / 2.0**level
        m = (np.array(n, dtype=np.int64) << (level + 1)) + 1
        split = []
        for c in range(0, len(keys), _CHUNK):  # bounded temporaries (9 points a cell)
            part = keys[c : c + _CHUNK]
            ijk = np.column_stack(_unpack(part, n, level))
            # Centres and corners in doubled integer coordinates; each distinct one once.
            corners = (2 * (ijk[:, None, :] + corner_off[None])).reshape(-1, 3)
            pts = np.concatenate([2 * ijk + 1, corners])
            flat = (pts[:, 0] * m[1] + pts[:, 1]) * m[2] + pts[:, 2]
            uniq, inverse = np.unique(flat, return_inverse=True)
            uz = np.column_stack([uniq // (m[1] * m[2]), (uniq // m[2]) % m[1], uniq % m[2]])
            values = _sample(h, lo + (0.5 * s) * uz.astype(np.float64), comm)[inverse.ravel()]
            hmin = np.minimum(values[: len(part)], values[len(part) :].reshape(-1, 8).min(axis=1))
            split.append(part[s > hmin * (1.0 + 1e-12)])
        refined.append(np.concatenate(split))
        keys = _children(refined[-1], n, level)
    while refined and not len(refined[-1]):
        refined.pop()
    return refined


def _sample(h: Callable[[Float], Float], x: Float, comm: MPI.Comm | None) -> Float:
    """``h(x)``; with several ranks each evaluates a slice (errors raised on every rank)."""
    if comm is None or comm.size == 1:
        return h(x)
    a, b = (len(x) * r // comm.size for r in (comm.rank, comm.rank + 1))
    try:
        mine, error = h(x[a:b]), None
    except Exception as e:  # a user size function failing on some ranks' points
        mine, error = np.zeros(b - a), f"{type(e).__name__}: {e}"
    gathered = comm.allgather((mine, error))
    errors = [e for _, e in gathered if e is not None]
    if errors:
        raise ValueError(f"the size function failed: {errors[0]}")
    return np.concatenate([v for v, _ in gathered])


def _balance(refined: list[Int], n: tuple[int, int, int]) -> list[Int]:
    """Corner-balance the octree: leaves that touch (share a face, an edge or a vertex)
    differ by at most one level.

    One sweep from the finest level to the coarsest: a leaf of level ``l`` needs each of its
    26 neighbouring cells of level ``l`` inside a node of level ``>= l - 1``, so the
    neighbour's grandparent (level ``l - 2``) is split; ancestors of split cells are split
    (closure). Requirements only create leaves at coarser levels, processed later.
    """
    refined = [r.copy() for r in refined] + [np.empty(0, dtype=np.int64)]
    for level in range(len(refined) - 1, 0, -1):
        if len(refined[level]):
            parents = _parents(refined[level], n, level)
            refined[level - 1] = _unique(np.concatenate([refined[level - 1], parents]))
        if level < 2:
            continue
        leaves = np.setdiff1d(
            _children(refined[level - 1], n, level - 1), refined[level], assume_unique=True
        )
        lim = np.array(n, dtype=np.int64) << level
        grand = [np.empty(0, dtype=np.int64)]
        for c in range(0, len(leaves), _CHUNK):
            i, j, k = _unpack(leaves[c : c + _CHUNK], n, level)
            ni = (i[:, None] + _NEIGHBOURS[:, 0]).ravel()
            nj = (j[:, None] + _NEIGHBOURS[:, 1]).ravel()
            nk = (k[:, None] + _NEIGHBOURS[:, 2]).ravel()
            ok = (ni >= 0) & (nj >= 0) & (nk >= 0) & (ni < lim[0]) & (nj < lim[1]) & (nk < lim[2])
            grand.append(_unique(_pack(ni[ok] >> 2, nj[ok] >> 2, nk[ok] >> 2, n, level - 2)))
        refined[level - 2] = _unique(np.concatenate([refined[level - 2], *grand]))
    while refined and not len(refined[-1]):
        refined.pop()
    return refined


def _leaves(refined: list[Int], n: tuple[int, int, int]) -> list[Int]:
    """Sorted keys of the leaves, per level ``0 .. len(refined)``."""
    out = []
    nodes = np.arange(n[0] * n[1] * n[2], dtype=np.int64)
    for level in range(len(refined) + 1):
        split = refined[level] if level < len(refined) else np.empty(0, dtype=np.int64)
        out.append(np.setdiff1d(nodes, split, assume_unique=True))
        nodes = _children(split, n, level)
    return out


def _octree(
    box: npt.ArrayLike,
    size: SizeLike,
    max_size: float,
    min_size: float | None,
    comm: MPI.Comm | None = None,
) -> _Octree:
    b = _check_box(box)
    lo, root, n, limit = _root_layout(b, max_size, min_size)
    h = _size_function(size)
    refined = _balance(_refine(h, lo, root, n, limit, comm), n)
    depth = len(refined)
    return _Octree(lo, root / 2.0 ** (depth + 1), n, depth, refined, _leaves(refined, n))


# ---------------------------------------------------------------------------------------------
# Classification of the leaves


class _Leaves(NamedTuple):
    """All leaves in Morton order, with what the tetrahedralisation needs of each."""

    level: Int  # (L,)
    ijk: Int  # (L, 3) cell indices at their level
    corner: Int  # (L, 3) lower corner, lattice units
    side: Int  # (L,) side, lattice units
    faces: Int  # (L, 6) face types, face id 2 d + s
    exists: Int  # (L,) bit p: position p is a vertex of the mesh
    owned: Int  # (L,) bit p: position p is a vertex owned by the leaf
    weight: Int  # (L,) tetrahedra generated by the leaf
    vstart: Int  # (L,) global number of the leaf's first owned vertex
    by_key: list[Int]  # per level: the Morton positions of its leaves, in key order


def _lattice_keys(xyz: Int, t: _Octree) -> Int:
    m = (np.array(t.n, dtype=np.int64) << (t.depth + 1)) + 1
    return (xyz[..., 0] * m[1] + xyz[..., 1]) * m[2] + xyz[..., 2]


def _lattice_coords(keys: Int, t: _Octree) -> Int:
    m = (np.array(t.n, dtype=np.int64) << (t.depth + 1)) + 1
    return np.stack([keys // (m[1] * m[2]), (keys // m[2]) % m[1], keys % m[2]], axis=-1)


def _member(sorted_keys: Int, q: Int) -> npt.NDArray[np.bool_]:
    if not len(sorted_keys):
        return np.zeros(q.shape, dtype=bool)
    pos = np.minimum(np.searchsorted(sorted_keys, q), len(sorted_keys) - 1)
    return sorted_keys[pos] == q


def _spread(v: Int) -> npt.NDArray[np.uint64]:
    """The 21 low bits of ``v`` spread to every third bit (Morton interleaving)."""
    x = v.astype(np.uint64) & np.uint64(0x1FFFFF)
    for shift, mask in (
        (32, 0x1F00000000FFFF),
        (16, 0x1F0000FF0000FF),
        (8, 0x100F00F00F00F00F),
        (4, 0x10C30C30C30C30C3),
        (2, 0x1249249249249249),
    ):
        x = (x | (x << np.uint64(shift))) & np.uint64(mask)
    return x


def _bit(p: int | Int) -> Int:
    return np.left_shift(np.int64(1), np.asarray(p, dtype=np.int64))


_ALWAYS = int(sum(1 << int(p) for p in np.flatnonzero((_KIND == 0) | (_KIND == 3))))
_EDGE_POS = np.flatnonzero(_KIND == 1)


def _classify(t: _Octree) -> _Leaves:
    """Face types, vertex positions and tetrahedron counts of every leaf; Morton order."""
    levels, ijks, faces, exists = [], [], [], []
    for lev, keys in enumerate(t.leaves):
        i, j, k = _unpack(keys, t.n, lev)
        ijk = np.column_stack([i, j, k])
        lim = np.array(t.n, dtype=np.int64) << lev
        split = t.refined[lev] if lev < len(t.refined) else np.empty(0, dtype=np.int64)
        ftype = np.empty((len(keys), 6), dtype=np.int64)
        for d in range(3):
            for s in range(2):
                nb = ijk.copy()
                nb[:, d] += 2 * s - 1
                inside = (nb[:, d] >= 0) & (nb[:, d] < lim[d])
                nk = _pack(nb[:, 0], nb[:, 1], nb[:, 2], t.n, lev)
                ft = np.where(
                    _member(split, nk), _FINER, np.where(_member(keys, nk), _SAME, _COARSER)
                )
                ftype[:, 2 * d + s] = np.where(inside, ft, _BOUNDARY)
        lside = 1 << (t.depth + 1 - lev)
        lcorner = ijk * lside
        ex = np.full(len(keys), _ALWAYS, dtype=np.int64)
        if len(split):  # edge midpoints: those of the edges of this level's split cells
            si, sj, sk = _unpack(split, t.n, lev)
            sc = np.column_stack([si, sj, sk]) * lside
            emid = _unique(_lattice_keys(sc[:, None, :] + _OFFSETS[_EDGE_POS] * (lside // 2), t))
            for p in _EDGE_POS:
                q = _lattice_keys(lcorner + _OFFSETS[p] * (lside // 2), t)
                ex |= _member(emid, q).astype(np.int64) << np.int64(p)
        for f, (*_, centre) in enumerate(_FACES):
            has = (ftype[:, f] == _FINER) | (ftype[:, f] == _BOUNDARY)
            ex |= has.astype(np.int64) << np.int64(centre)
        levels.append(np.full(len(keys), lev, dtype=np.int64))
        ijks.append(ijk)
        faces.append(ftype)
        exists.append(ex)
    level = np.concatenate(levels)
    ijk = np.concatenate(ijks)
    ftype = np.concatenate(faces)
    ex = np.concatenate(exists)
    side = np.left_shift(np.int64(1), t.depth + 1 - level)
    corner = ijk * side[:, None]
    # Morton order of the lower corners (distinct: the leaves are disjoint).
    fine = corner // 2
    morton = (_spread(fine[:, 0]) << np.uint64(2)) | (_spread(fine[:, 1]) << np.uint64(1))
    morton |= _spread(fine[:, 2])
    order = np.argsort(morton, kind="stable")
    position = np.empty_like(order)
    position[order] = np.arange(len(order))
    bounds = np.cumsum([0] + [len(k) for k in t.leaves])
    by_key = [position[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    level, ijk, ftype, ex, side, corner = (a[order] for a in (level, ijk, ftype, ex, side, corner))
    # Owned positions: offsets 0 and 1, and 2 along an axis where the leaf reaches the top.
    top = corner + side[:, None] == np.array(t.n, dtype=np.int64) << (t.depth + 1)
    own = np.zeros(len(level), dtype=np.int64)
    for pos, off in enumerate(_OFFSETS):
        ok = np.all((off < 2) | top, axis=1)
        own |= ok.astype(np.int64) << np.int64(pos)
    own &= ex
    # Tetrahedra per leaf.
    weight = np.zeros(len(level), dtype=np.int64)
    for f, (_, s, _, mids, _) in enumerate(_FACES):
        nsplit = sum((ex >> np.int64(m)) & 1 for m in mids)
        ft = ftype[:, f]
        weight += np.select(
            [ft == _BOUNDARY, ft == _COARSER, ft == _FINER],
            [4 + nsplit, np.full_like(nsplit, 2), np.full_like(nsplit, 8)],
            (4 + nsplit) * s,  # equal neighbour: generated by the leaf below it
        )
    count = np.bitwise_count(own).astype(np.int64)
    vstart = np.cumsum(count) - count
    return _Leaves(level, ijk, corner, side, ftype, ex, own, weight, vstart, by_key)


def _leaf_parts(lv: _Leaves, nparts: int) -> Int:
    """Part of each leaf (Morton order): contiguous runs of about equal tetrahedron counts."""
    w = lv.weight
    start = np.cumsum(w) - w
    return (start * nparts // max(int(w.sum()), 1)).astype(np.int64)


def _vertex_numbers(t: _Octree, lv: _Leaves, keys: Int) -> Int:
    """Global vertex numbers of lattice points (vertices of the mesh), by their owning leaf:
    the leaf containing the point pushed by ``(+eps, +eps, +eps)`` (clamped to the box)."""
    xyz = _lattice_coords(keys, t)
    top = np.array(t.n, dtype=np.int64) << (t.depth + 1)
    clamp = np.minimum(xyz, top - 1)
    leaf = np.full(len(keys), -1, dtype=np.int64)
    for level, keys_l in enumerate(t.leaves):
        if not len(keys_l):
            continue
        c = clamp >> (t.depth + 1 - level)
        q = _pack(c[:, 0], c[:, 1], c[:, 2], t.n, level)
        pos = np.minimum(np.searchsorted(keys_l, q), len(keys_l) - 1)
        hit = keys_l[pos] == q
        leaf[hit] = lv.by_key[level][pos[hit]]
    if np.any(leaf < 0):  # pragma: no cover - a bug, not an input error
        raise RuntimeError("graded_tet: a vertex outside every leaf")
    rel = xyz - lv.corner[leaf]
    half = (lv.side[leaf] // 2)[:, None]
    off = rel // half
    p = off[:, 0] * 9 + off[:, 1] * 3 + off[:, 2]
    bad = np.any(rel != off * half, axis=1) | np.any((off < 0) | (off > 2), axis=1)
    if np.any(bad) or np.any(((lv.owned[leaf] >> p) & 1) == 0):  # pragma: no cover
        raise RuntimeError("graded_tet: a vertex that its leaf does not own")
    below = lv.owned[leaf] & (_bit(p) - 1)
    return lv.vstart[leaf] + np.bitwise_count(below).astype(np.int64)


# ---------------------------------------------------------------------------------------------
# Tetrahedra


def _leaf_tets(lv: _Leaves, sel: Int) -> tuple[Int, Int]:
    """Tetrahedra generated by the leaves ``sel`` (Morton positions, one level): lattice
    coordinates ``(m, 4, 3)`` (positively oriented) and a sort key ``(m,)`` (Morton position,
    then a local index in ``0 .. 47``)."""
    if not len(sel):
        return np.empty((0, 4, 3), dtype=np.int64), np.empty(0, dtype=np.int64)
    corner, half = lv.corner[sel], (lv.side[sel] // 2)[:, None]
    ex, ijk = lv.exists[sel], lv.ijk[sel]

    def at(p: int | Int) -> Int:
        return corner + _OFFSETS[p] * half

    c = at(_CENTRE)
    out: list[Int] = []
    lids: list[Int] = []

    def emit(rows: Int, pts: list[Int], lid: int) -> None:
        if len(rows):
            out.append(np.stack([q[rows] for q in pts], axis=1))
            lids.append(sel[rows] * 64 + lid)

    for f, (d, s, corners, mids, centre) in enumerate(_FACES):
        ft = lv.faces[sel, f]
        apex = {_SAME: c + 2 * half * np.eye(3, dtype=np.int64)[d], _FINER: at(centre)}
        apex[_BOUNDARY] = apex[_FINER]
        for kind in (_SAME, _BOUNDARY, _FINER):
            rows = np.flatnonzero(ft == kind) if kind != _SAME or s == 1 else np.empty(0, int)
            if not len(rows):
                continue
            for t in range(4):
                a, b, m = at(corners[t]), at(corners[(t + 1) % 4]), at(mids[t])
                split = ((ex[rows] >> np.int64(mids[t])) & 1).astype(bool)
                lid = (f * 4 + t) * 2
                emit(rows[~split], [c, apex[kind], a, b], lid)
                emit(rows[split], [c, apex[kind], a, m], lid)
                emit(rows[split], [c, apex[kind], m, b], lid + 1)
        rows = np.flatnonzero(ft == _COARSER)
        if len(rows):  # half pyramids, split by the diagonal through the larger face's centre
            d1, d2 = (d + 1) % 3, (d + 2) % 3
            p1, p2 = ijk[rows, d1] & 1, ijk[rows, d2] & 1

            def quarter(u: Int, v: Int, rows: Int = rows, d: int = d, s: int = s) -> Int:
                o = np.zeros((len(rows), 3), dtype=np.int64)
                o[:, d], o[:, (d + 1) % 3], o[:, (d + 2) % 3] = 2 * s, u, v
                return corner[rows] + o * half[rows]

            c0, c2 = quarter(2 - 2 * p1, 2 - 2 * p2), quarter(2 * p1, 2 * p2)
            x1, x2 = quarter(2 - 2 * p1, 2 * p2), quarter(2 * p1, 2 - 2 * p2)
            idx = np.arange(len(rows))
            emit_rows = rows  # the stacked points below are already restricted to ``rows``
            out.append(np.stack([c[emit_rows], c0[idx], x1[idx], c2[idx]], axis=1))
            out.append(np.stack([c[emit_rows], c0[idx], x2[idx], c2[idx]], axis=1))
            lids += [sel[rows] * 64 + f * 8, sel[rows] * 64 + f * 8 + 1]
    tets = np.concatenate(out)
    e = (tets[:, 1:] - tets[:, :1]).astype(np.float64)
    neg = np.linalg.det(e) < 0
    tets[neg, 2], tets[neg, 3] = tets[neg, 3].copy(), tets[neg, 2].copy()
    return tets, np.concatenate(lids)


def _part(t: _Octree, lv: _Leaves, parts: Int, rank: int) -> tuple[Float, Int]:
    """Vertices (the block owned by part ``rank``) and cells (global vertex numbers) of part
    ``rank``: the leaves ``parts == rank`` (a contiguous run in Morton order)."""
    mine = np.flatnonzero(parts == rank)
    tets, order = [], []
    for level in range(t.depth + 1):
        sel = mine[lv.level[mine] == level]
        tt, key = _leaf_tets(lv, sel)
        tets.append(tt)
        order.append(key)
    allt = np.concatenate(tets)
    keys = _lattice_keys(allt, t)  # (m, 4)
    uniq, inverse = np.unique(keys, return_inverse=True)
    cells = _vertex_numbers(t, lv, uniq)[inverse.reshape(-1)].reshape(-1, 4)
    cells = cells[np.argsort(np.concatenate(order), kind="stable")]
    # Owned vertices, by leaf then position.
    bits = ((lv.owned[mine][:, None] >> np.arange(27, dtype=np.int64)) & 1).astype(bool)
    leaf, p = np.nonzero(bits)
    xyz = lv.corner[mine][leaf] + _OFFSETS[p] * (lv.side[mine][leaf] // 2)[:, None]
    x = t.lo + t.unit * xyz.astype(np.float64)
    return x, cells


def graded_tetrahedralisation(
    box: npt.ArrayLike,
    size: SizeLike,
    max_size: float,
    min_size: float | None = None,
) -> tuple[Float, Int]:
    """Vertices and positively oriented cells of the graded BCC tetrahedralisation of a box.

    The box is covered by root cubes of side ``max_size`` (or the largest ``min_size 2^k``
    not above it), a block of them centred on the box. A cube of side ``s`` is split into 8
    while ``s`` exceeds the target size at its centre or at one of its corners (so no edge
    is longer than the target there: the longest BCC edges have the leaf's side), down to
    ``min_size``; the octree is corner-balanced and tetrahedralised as in the module notes.
    The mesh's boundary is the surface of the root cubes.

    Parameters
    ----------
    box
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``, the box to cover.
    size
        Target size: a positive float, or a vectorised callable mapping points ``(n, 3)`` to
        sizes ``(n,)`` (e.g. a :class:`BandSizeField`).
    max_size
        Largest leaf side.
    min_size
        Smallest leaf side (default ``max_size 2^-20``); given, every leaf side is
        ``min_size 2^k``.

    Returns
    -------
    x
        Vertex coordinates, shape ``(num_vertices, 3)``.
    cells
        Vertex indices of each tetrahedron (positive signed volume), shape ``(num_cells, 4)``.
    """
    t = _octree(box, size, max_size, min_size)
    lv = _classify(t)
    return _part(t, lv, np.zeros(len(lv.level), dtype=np.int64), 0)


def graded_tet_mesh(
    comm: MPI.Comm,
    box: Sequence[Sequence[float]] | npt.ArrayLike,
    size: SizeLike,
    max_size: float,
    min_size: float | None = None,
) -> dmesh.Mesh:
    """Distributed graded BCC tetrahedral mesh of a box (see
    :func:`graded_tetrahedralisation`), built in parallel.

    Every rank holds the octree (keys only) and classifies its leaves; the size is sampled in
    parallel (each rank evaluates a slice of each level's points, the values are gathered;
    an exception in ``size`` is raised on every rank as a ``ValueError``). Rank ``r`` takes
    the ``r``-th run of leaves of equal tetrahedron counts along the Morton order, generates
    their tetrahedra and the vertices their leaves own (a contiguous block of the global
    numbering) and owns them (:func:`~dolfinx_universal.backgrounds.lattice_tri.layout_partitioner`,
    shared-facet ghosts, no graph partitioning). The global mesh (vertex coordinates by input
    index, cells) is bitwise the serial one on any number of ranks.

    Parameters
    ----------
    comm
        Communicator.
    box, size, max_size, min_size
        As in :func:`graded_tetrahedralisation`.

    Returns
    -------
    A DOLFINx tetrahedral mesh with degree-1 geometry and shared-facet ghosts.
    """
    return graded_octree(box, size, max_size, min_size, comm).mesh(comm)


class GradedOctree(NamedTuple):
    """A balanced octree of a box with its leaves classified: the tetrahedra of
    :func:`graded_tet_mesh`, counted before they are built."""

    tree: _Octree
    leaves: _Leaves

    @property
    def num_cells(self) -> int:
        """Tetrahedra of the mesh."""
        return int(self.leaves.weight.sum())

    def mesh(self, comm: MPI.Comm) -> dmesh.Mesh:
        """The distributed mesh (collective; see :func:`graded_tet_mesh`)."""
        return _mesh(comm, self.tree, self.leaves)


def graded_octree(
    box: Sequence[Sequence[float]] | npt.ArrayLike,
    size: SizeLike,
    max_size: float,
    min_size: float | None = None,
    comm: MPI.Comm | None = None,
) -> GradedOctree:
    """The octree of :func:`graded_tet_mesh` (arguments as there; ``size`` sampled in
    parallel over ``comm`` when given), to count its tetrahedra before building them."""
    t = _octree(box, size, max_size, min_size, comm)
    return GradedOctree(t, _classify(t))


def _mesh(comm: MPI.Comm, t: _Octree, lv: _Leaves) -> dmesh.Mesh:
    """The distributed mesh of a classified octree (the same on every rank)."""
    x, cells = _part(t, lv, _leaf_parts(lv, comm.size), comm.rank)
    return create_mesh(
        comm, cells, x, layout_partitioner() if comm.size > 1 else None, "tetrahedron"
    )
