"""What the vertex relaxations of triangles and tetrahedra share: result, frame, colouring.

Both relaxations (:mod:`~dolfinx_universal.conforming.relax_tri`,
:mod:`~dolfinx_universal.conforming.relax_tet`) move the same vertices
(:func:`movable_vertices`), as a sub index map over which values are reduced
(:class:`SubVertices`), in colour classes (Jones & Plassmann 1993, first fit: no two
vertices of one colour share a cell) whose priorities are hashed from the background
coordinates (:func:`coordinate_priority`, or in a :class:`RelaxFrame`), so that the colours,
and therefore the result, do not depend on the partition.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import la
from dolfinx.cpp.common import create_sub_index_map

from dolfinx_universal.core.arrays import Bool, Float, Int
from dolfinx_universal.core.collective import combine_ghosts, reduce_sign, vertex_reduce

if TYPE_CHECKING:
    from dolfinx.common import IndexMap

__all__ = [
    "FRAME_GRID",
    "GAMMA_EDGE_MAX",
    "INITIAL_STEP",
    "MAX_COLOURS",
    "MAX_STEP",
    "TIE",
    "Relaxation",
    "RelaxFrame",
    "SubVertices",
    "coordinate_priority",
    "movable_vertices",
    "vertex_colours",
    "vertex_colours_graph",
    "vertex_priority",
]

INITIAL_STEP = 0.25
"""First step of a vertex, in units of its mesh size ``h``."""
MAX_STEP = 0.5
"""Largest step of a vertex, in units of ``h``."""
GAMMA_EDGE_MAX = 1.0
"""Longest edge of Gamma_h a slide may make, in units of the larger ``h`` of its two
vertices (edges longer after ``M_h`` may keep, not exceed, their length): the geometric
error of a curved edge grows like its length to the power q + 1."""
TIE = 1e-9
"""Qualities closer than this count as equal. The relaxations' qualities are dimensionless
O(1) values computed to a few ulps (about 1e-15); candidates of symmetric stars (equilateral
backgrounds) tie up to such rounding, and a decision taken on a 1e-16 difference would
change when the input changes by rounding (the same domain given through another
parametrisation), and then the mesh by a whole step. 1e-9 is far above rounding and far
below any gain that matters (steps stop at ``MIN_STEP h``, which moves a quality by about
1e-3)."""
MAX_COLOURS = 62
"""Most colours a colouring may use (the bits of the colour masks)."""


class Relaxation(NamedTuple):
    """Result of :func:`relax_vertices` (process-local arrays, owned and ghost vertices)."""

    y: Float
    """Relaxed vertex images ``(num_vertices, gdim)``."""
    x: Float
    """Background positions; those of the vertices slid along Gamma moved with them
    (``pi(x) = y`` there, as the curved maps need) ``(num_vertices, gdim)``."""
    moved: Bool
    """Vertices whose image differs from their original position ``(num_vertices,)``."""
    num_moves: int
    """Accepted moves, over all sweeps and ranks."""
    num_sweeps: int
    """Sweeps made."""


def coordinate_priority(x: Float) -> Float:
    """Pseudo-random priorities in ``[0, 1)`` hashed from coordinates ``(n, 2)``, ``(n,)``.

    A function of the coordinates' bits only (splitmix64), so that a vertex has the same
    priority on every rank and for every partition.
    """
    bits = np.ascontiguousarray(x, dtype=np.float64).view(np.uint64)

    def mix(z: npt.NDArray[np.uint64]) -> npt.NDArray[np.uint64]:
        z = z + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))

    with np.errstate(over="ignore"):
        inner = mix(bits[:, -1])
        for k in range(bits.shape[1] - 2, -1, -1):  # 2D: mix(b0 ^ mix(b1))
            inner = mix(bits[:, k] ^ inner)
        z = inner
    return (z >> np.uint64(11)).astype(np.float64) * 2.0**-53


class RelaxFrame(NamedTuple):
    """A frame for the vertex relaxation: positions ``x`` have frame coordinates
    ``(x - origin) @ rotation``, and directions are taken in the frame (``d @ rotation.T``
    in the world). The relaxation's choices (colour priorities, search directions) then
    move with the frame: a rigid motion of the domain and the frame that maps the
    background onto itself maps the relaxed mesh onto the relaxed mesh."""

    rotation: Float
    """Rotation matrix ``(gdim, gdim)``: frame axes in world coordinates (its columns)."""
    origin: Float
    """Origin ``(gdim,)`` of the frame in world coordinates."""
    mirror: int | None = None
    """A frame axis normal to a mirror plane through the origin (or ``None``): the choices
    are then also symmetric under the reflection ``y_mirror -> -y_mirror``. A vertex and
    its mirror image get one priority (up to the last bit, which orders them), the search
    directions of the vertices on the negative side are the mirror images of those on the
    positive side, and the vertices on the plane move in it (their slides along Gamma
    stop): on a mirror-symmetric background and domain the relaxed mesh is symmetric, to
    rounding, where the colouring is (vertices whose stars reach beyond the symmetric part
    of the background may differ)."""

    def directions(self, d: Float) -> Float:
        """Directions ``(..., gdim)`` given in the frame, in world coordinates."""
        return np.asarray(d) @ self.rotation.T

    def priority(self, x: Float) -> Float:
        """:func:`coordinate_priority` of the frame coordinates of ``x`` ``(n, gdim)``.

        The frame coordinates of the same background vertex at two symmetric positions
        differ by rounding, so they are snapped to a grid of :data:`FRAME_GRID` (a fixed
        length: the same on every rank) before hashing: equal unless a coordinate lies
        within rounding of a grid line (coordinates up to about ``1e3`` round by less than
        ``1e-13``). With a :attr:`mirror`, the hash is that of the distance to the plane
        (and the other coordinates), its last bit replaced by the side of the plane.
        """
        y = (np.asarray(x, dtype=np.float64) - self.origin) @ self.rotation
        if self.mirror is None:
            return coordinate_priority(np.floor(y / FRAME_GRID + _FRAME_OFFSET))
        side = y[:, self.mirror] >= FRAME_GRID  # (side(x) > 0)
        y[:, self.mirror] = np.abs(y[:, self.mirror])
        bits = np.ldexp(coordinate_priority(np.floor(y / FRAME_GRID + _FRAME_OFFSET)), 53)
        return np.ldexp(2.0 * np.floor(bits / 2.0) + side, -53)

    def side(self, x: Float) -> npt.NDArray[np.int64]:
        """The side of the mirror plane of points ``x`` ``(n, gdim)``: +1, -1, and 0 within
        :data:`FRAME_GRID` of the plane (all +1 without a mirror), ``(n,)``."""
        x = np.asarray(x, dtype=np.float64)
        if self.mirror is None:
            return np.ones(len(x), dtype=np.int64)
        y = (x - self.origin) @ self.rotation[:, self.mirror]
        return np.where(np.abs(y) < FRAME_GRID, 0, np.sign(y)).astype(np.int64)


FRAME_GRID = 2.0**-36
"""Grid (in length units) that :meth:`RelaxFrame.priority` snaps frame coordinates to."""
_FRAME_OFFSET = 0.3183098861837907
"""1 / pi: the grid's offset in cells (lattice coordinates are round numbers)."""


def vertex_priority(x0: Float, frame: RelaxFrame | None) -> Float:
    """The colour priorities of vertices at background positions ``x0`` ``(n, gdim)``:
    :func:`coordinate_priority`, or :meth:`RelaxFrame.priority` in ``frame``."""
    return coordinate_priority(x0) if frame is None else frame.priority(x0)


class SubVertices:
    """The movable vertices as a (sub) index map: reductions over them only."""

    def __init__(self, imv: IndexMap, vertices: Int) -> None:
        self.comm: MPI.Comm = imv.comm
        if self.comm.size == 1:
            self.map = None
            self.vertices = np.asarray(vertices, dtype=np.int32)
            self.size_local = len(self.vertices)
        else:
            self.map, parent = create_sub_index_map(imv, np.asarray(vertices, np.int32), False)
            self.vertices = np.asarray(parent, dtype=np.int32)
            self.size_local = self.map.size_local
        self._row_vectors: dict[str, tuple[int, la.Vector, Any]] = {}
        self.shared = self._shared_vertices()
        self._is_shared = np.zeros(len(self.vertices), dtype=bool)
        self._is_shared[self.shared] = True

    def _shared_vertices(self) -> Int:
        """The sub indices of the vertices other ranks also hold: this rank's ghosts and the
        owned vertices that are ghosts elsewhere (collective; empty on one rank). Only
        their values take part in a reduction over the ranks."""
        if self.map is None:
            return np.zeros(0, dtype=np.int64)
        n = self.map.size_local
        v = la.vector(self.map, 1, dtype=np.float64)
        v.array[:n] = 0.0
        v.array[n:] = 1.0
        combine_ghosts(v.petsc_vec, "sum")  # owned entries: how many ranks ghost them
        return np.concatenate([np.flatnonzero(v.array[:n] > 0), np.arange(n, len(v.array))])

    def reduce(self, values: Float, op: str) -> Float:
        """``values`` (one row per sub vertex) reduced over the ranks with ``op``
        (:func:`~dolfinx_universal.core.collective.vertex_reduce`; collective): the rows of the
        shared vertices are reduced, the others are this rank's alone and stay."""
        if self.map is None:
            return values
        out = np.array(values, dtype=np.float64)
        out[self.shared] = self.reduce_rows(self.shared, out[self.shared], op)
        return out

    def reduce_rows(self, rows: Int, values: Float, op: str) -> Float:
        """:meth:`reduce` of the values ``(len(rows), ...)`` of the vertices ``rows`` (sub
        indices), this rank's other rows taken as the neutral element of ``op`` (``inf``
        for "min", ``-inf`` for "max", 0 for "sum"): the reduced values of ``rows``
        (collective; each rank may give other rows).

        The work is that of ``rows`` and of the vertices shared with other ranks, not of all
        movable vertices: a colour visit's reductions copied and scattered the values of
        every movable vertex of the rank. A vector per ``op`` keeps the neutral element
        between calls; only the shared ones of ``rows`` are written, and the shared rows
        are reset after.
        """
        sign = reduce_sign(op)
        if self.map is None:
            return values
        values = np.asarray(values, dtype=np.float64)
        out = values.copy()
        sh = np.flatnonzero(self._is_shared[rows])  # the others have nothing to combine
        rows, values = rows[sh], values[sh]
        width = 1 if values.ndim == 1 else int(np.prod(values.shape[1:]))
        neutral = 0.0 if op == "sum" else -np.inf  # as stored (times sign)
        vec = self._row_vectors.get(op)
        if vec is None or vec[0] < width:  # (a power of two: few vectors as widths grow)
            bs = max(16, 1 << (width - 1).bit_length())
            v = la.vector(self.map, bs, dtype=np.float64)
            v.array[:] = neutral
            vec = self._row_vectors[op] = (bs, v, v.petsc_vec)
        bs, v, pv = vec
        arr = v.array.reshape(-1, bs)
        arr[rows, :width] = sign * values.reshape(len(rows), width)
        combine_ghosts(pv, op)
        out[sh] = (sign * arr[rows, :width]).reshape(values.shape)
        # Back to neutral: the rows written, and every other shared row the scatters may
        # have filled (an owner's row takes the ghosts' values even where it gave none).
        arr[self.shared, :width] = neutral
        return out

    def combine_bits(self, used: npt.NDArray[np.int64], bits: npt.NDArray[np.int64]) -> None:
        """OR the bit masks ``used`` (one per sub vertex, bits among ``bits``) of the shared
        vertices over the ranks, in place (collective; nothing on one rank): the colourings'
        masks of the colours taken around each vertex."""
        if self.map is None:
            return
        sh = self.shared  # (the other vertices' bits are this rank's alone)
        flags = ((used[sh, None] & bits[None]) > 0).astype(np.float64)
        used[sh] = (self.reduce_rows(sh, flags, "max") > 0).astype(np.int64) @ bits


def vertex_colours(sub: SubVertices, cells: Int, priority: Float) -> Int:
    """Colour vertices so that no two of one colour share a triangle (collective).

    Jones-Plassmann with first fit: in each round the uncoloured vertices whose priority is
    the largest among the uncoloured vertices of their triangles (on every rank) take the
    smallest colour that no vertex of their triangles has yet.

    Parameters
    ----------
    sub
        The vertices to colour ``(m,)``.
    cells
        Triangles (owned, each on one rank) in the numbering of ``sub``, -1 for vertices not
        to colour, ``(k, 3)``.
    priority
        Distinct priorities of the vertices ``(m,)``, the same on every rank.

    Returns
    -------
    Colours ``0, 1, ...`` of the vertices ``(m,)``.
    """
    m = len(sub.vertices)
    colour = np.full(m, -1, dtype=np.int64)
    valid = cells >= 0
    corner = np.where(valid, cells, 0)
    # Corners sorted by vertex: per-vertex reductions over its triangles are segments.
    cell_of, _ = np.nonzero(valid)
    vc = cells[valid]
    order = np.argsort(vc, kind="stable")
    cell_of, vc = cell_of[order], vc[order]
    starts = np.flatnonzero(np.diff(vc, prepend=-1))
    seg = vc[starts]
    bits = 2 ** np.arange(MAX_COLOURS, dtype=np.int64)
    used = np.zeros(m, dtype=np.int64)  # bit c: a vertex of colour c shares a triangle
    while sub.comm.allreduce(bool((colour[: sub.size_local] < 0).any()), op=MPI.LOR):
        pr = np.where(valid & (colour[corner] < 0), priority[corner], -1.0).max(axis=1)
        vmax = np.full(m, -1.0)
        if len(starts):
            vmax[seg] = np.maximum.reduceat(pr[cell_of], starts)
        vmax = sub.reduce(vmax, "max")
        new = np.flatnonzero((colour < 0) & (vmax <= priority))
        free = (used[new, None] & bits[None]) == 0
        if len(new) and not free.any(axis=1).all():
            raise RuntimeError(f"vertex colouring: more than {MAX_COLOURS} colours needed")
        colour[new] = np.argmax(free, axis=1)
        # Record the new colours in the masks of the vertices sharing a triangle.
        cbits = np.where(valid & (colour[corner] >= 0), 2 ** np.maximum(colour[corner], 0), 0)
        cmask = np.bitwise_or.reduce(cbits, axis=1)
        if len(starts):
            used[seg] |= np.bitwise_or.reduceat(cmask[cell_of], starts)
        sub.combine_bits(used, bits)
    return colour


def vertex_colours_graph(sub: SubVertices, cells: Int, priority: Float) -> Int:
    """The colours of :func:`vertex_colours`, on the vertex graph (collective).

    The same Jones-Plassmann rounds with first fit, on the distinct pairs of vertices that
    share a cell. Each vertex counts its uncoloured neighbours of higher priority (on each
    rank, over the pairs it has; a vertex is free when no rank counts one), and a round
    visits only the pairs of the vertices it colours: the counts and colour masks of their
    uncoloured neighbours are updated there, so that all rounds together read each pair
    about once.
    """
    m = len(sub.vertices)
    colour = np.full(m, -1, dtype=np.int64)
    k = cells.shape[1]
    pairs = [(i, j) for i in range(k) for j in range(i + 1, k)]
    src = np.concatenate([cells[:, i] for i, _ in pairs]).astype(np.int64)
    dst = np.concatenate([cells[:, j] for _, j in pairs]).astype(np.int64)
    keep = (src >= 0) & (dst >= 0)
    src, dst = src[keep], dst[keep]
    src, dst = np.minimum(src, dst), np.maximum(src, dst)
    key = np.sort(src * m + dst)
    key = key[np.diff(key, prepend=-1) != 0]  # distinct edges, then both directions
    src, dst = key // m, key % m
    key = np.sort(np.concatenate([key, dst * m + src]))  # sorted by their first vertex
    src, dst = key // m, key % m
    ptr = np.searchsorted(src, np.arange(m + 1))  # each vertex's pairs
    # The uncoloured neighbours of higher priority that each vertex waits for.
    waits = np.bincount(src[priority[dst] > priority[src]], minlength=m).astype(np.float64)
    used = np.zeros(m, dtype=np.int64)  # bit c: a neighbour has colour c
    while sub.comm.allreduce(bool((colour[: sub.size_local] < 0).any()), op=MPI.LOR):
        new = np.flatnonzero((colour < 0) & (sub.reduce(waits, "max") <= 0.0))
        un = used[new]
        free = ~un & (un + 1)  # the lowest colour not used
        if len(new) and (free.min() <= 0 or free.max() >= 2**MAX_COLOURS):
            raise RuntimeError(f"vertex colouring: more than {MAX_COLOURS} colours needed")
        colour[new] = np.round(np.log2(free.astype(np.float64))).astype(np.int64)
        # The pairs of the new vertices with their uncoloured neighbours, all of lower
        # priority: one fewer to wait for, and the new colour in their masks.
        cnt = ptr[new + 1] - ptr[new]
        at = np.repeat(ptr[new] - (np.cumsum(cnt) - cnt), cnt) + np.arange(cnt.sum())
        nb, c = dst[at], np.repeat(colour[new], cnt)
        open_ = colour[nb] < 0
        nb, c = nb[open_], c[open_]
        waits -= np.bincount(nb, minlength=m)
        np.bitwise_or.at(used, nb, np.left_shift(1, c))
        if sub.map is not None:
            nbits = sub.comm.allreduce(int(colour.max(initial=-1)) + 1, op=MPI.MAX)
            sub.combine_bits(used, 2 ** np.arange(nbits, dtype=np.int64))
    return colour


def movable_vertices(
    imv: IndexMap, sign: Float, band: Int, on_gamma: Bool, in_kept: Bool, fixed: Int
) -> Bool:
    """The vertices the relaxation may move, agreed on by every rank (collective).

    Inside vertices of the band and the vertices on Gamma, except ``fixed`` ones (the
    background's outer boundary, known on some ranks only) and vertices of no kept triangle.

    Parameters
    ----------
    imv
        Vertex index map.
    sign
        Vertex signs ``(num_vertices,)``.
    band
        Band vertices (within ``R_r`` of Gamma) ``(num_band,)``.
    on_gamma
        Vertices snapped onto Gamma ``(num_vertices,)``.
    in_kept
        Vertices of a kept triangle near Gamma ``(num_vertices,)``.
    fixed
        Vertices that must not move ``(n,)``.

    Returns
    -------
    ``(num_vertices,)`` flags.
    """
    flag = np.zeros(len(sign))
    inside_band = np.zeros(len(sign), dtype=bool)
    inside_band[band] = sign[band] < 0
    flag[(inside_band | on_gamma) & in_kept] = 1.0
    flag[fixed] = 0.0
    return vertex_reduce(imv, flag, "min") > 0
