"""Directional vertex relaxation of tetrahedra: a line search along an ascent direction.

The same max-min problem as in 2D (each movable vertex raises the worst quality of the
tetrahedra around it, the vertices on Gamma slide along Gamma), solved along one direction
per vertex and visit instead of by a compass search, in the spirit of the directional
vertex relaxation of Rangarajan & Lew (SIAM J. Sci. Comput. 2017): along a line
``p + t d`` the quality of every tetrahedron of the star is a closed-form function of
``t``, ``q(t) = cbrt(s + t sigma)^2 / (L + t (2 beta + t))`` (the signed mean ratio over
the target of :func:`_tetrahedron.star_quality`: ``s`` is ``6 V`` scaled, ``L`` the sum
of the squared edge lengths over 3, both at ``t = 0``; ``sigma`` and ``beta`` two dot
products with ``d``), so the worst quality along the line is found at a few step lengths
for the cost of a few array passes each, without gathering or recomputing the facets.

The direction is an ascent direction of the star's minimum: the sum of the unit gradients
of the tetrahedra whose quality is within :data:`NEAR_WORST` of the worst one, each
weighted by how close it is (``1 - (q - q_min) / NEAR_WORST``: a continuous function of the
qualities, so that rounding cannot switch the direction). For one worst tetrahedron it is
its gradient; at a kink between two it is their bisector, which raises both. A vertex on
Gamma uses the direction's component in the tangent plane, and its candidates are
projected onto Gamma and rated exactly.

Each visit takes the first step length within
:data:`~dolfinx_universal.conforming.relax_common.TIE` of the best and accepts it only if it
raises the vertex's worst quality by more than ``TIE``, so the global minimum never falls,
as in 2D. A vertex is visited again only while it keeps gaining or after a neighbour moved:
a vertex that could not gain along its direction, or whose star meets the target with a
margin (:data:`ACTIVE_BELOW`), waits until its star changes.

The quality of every tetrahedron is kept (one value per cell, rated once at the start) and
set by the move that changes it, from the winning candidate's ratings of the mover's star
(no two corners of a tetrahedron move together): finding a vertex's worst tetrahedron
re-rates nothing, only the stars of the vertices worked on are rated, once per visit.
Tetrahedra are rated by the cube of their quality (:func:`rating`, ``s^2 / L^3``: no root),
and the cube root (:func:`cube_root`, the same on every machine) is taken once per star and
candidate.

On one rank the visits, the colouring and the set-up of the stars run as C kernels
(:mod:`_compiled`: ``dvr_colour``, ``dvr_orient``, ``dvr_visit``, ``dvr_slides``) that
evaluate this module's floating-point operations in its order, so that they move the
vertices bitwise as the numpy code does; the numpy code is the reference, the fallback and
the path on several ranks.

Rank independence: every decision is taken on values reduced over the ranks (minimum
qualities; the direction's sum, whose rounding may differ between partitions by a few
ulps, far below the tie tolerance), as in 2D.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from mpi4py import MPI

import numpy as np

from dolfinx_universal.cells import tet as tet
from dolfinx_universal.conforming.relax_common import (
    GAMMA_EDGE_MAX,
    INITIAL_STEP,
    MAX_COLOURS,
    MAX_STEP,
    TIE,
    Relaxation,
    RelaxFrame,
    SubVertices,
    vertex_colours_graph,
    vertex_priority,
)
from dolfinx_universal.core.arrays import Bool, Float, Int
from dolfinx_universal.core.collective import collective_call
from dolfinx_universal.core.compiled import pointer, relax_kernels

if TYPE_CHECKING:
    from dolfinx.common import IndexMap

__all__ = [
    "ascent_gradients",
    "cube_root",
    "line_rating",
    "rating",
    "rating_quality",
    "relax_tetrahedra",
    "star_terms",
]

SWEEPS = 6
"""Sweeps over all colours (fewer when a sweep moves nothing). On the 1e6-tetrahedron A15
backgrounds of ``benchmarks/conform_floor_3d.py`` (ball r = 0.8, torus), step 0, 4 sweeps
gave the same extreme dihedral angles as 6 to within 0.5 degrees, but not at step 1: the
torus reaches [32.1, 124.3] degrees after 4 sweeps, [34.4, 121.1] after 5, [34.6, 120.4]
after 6 and [35.0, 119.3] after 8 (the ball [33.6, 118.2], [33.8, 118.1], [34.3, 118.1],
[34.5, 117.5]); each sweep after the third costs about a tenth of the relaxation."""
ACTIVE_BELOW = 1.0
"""A vertex is worked on only while its worst tetrahedron is below the target mean ratio
(:data:`_tetrahedron.TARGET_MEAN_RATIO`, quality 1). The compass search used 1.05; with
exact line searches 1.05 moves twice as many vertices for the same extreme angles on the
1e6 ball and torus (34.96-117.98 against 34.96-118.11 degrees on the ball). A lower bar
after the first sweep does not pay either: working only on stars within 0.1 of the worst
quality then halves the relaxation's time on the moving ball and torus of
``benchmarks/curved_floor_3d.py`` (302 -> 154 and 248 -> 95 ms) but leaves their smallest
dihedral angles at 27.4 and 25.5 degrees instead of 34.8 and 32.8: the worst tetrahedra
need their neighbours' stars relaxed too."""
_ACTIVE_RATING = ACTIVE_BELOW**3
"""The rating (:func:`rating`) of the quality :data:`ACTIVE_BELOW`."""
NEAR_WORST = 0.02
"""Tetrahedra within this quality of the star's worst one shape the direction. Measured on
the six lattice/surface cases of ``tests/test_conform_3d.py`` (h = 0.25): 0.05 and 0.15
leave the coarse torus on BCC at 29.2-29.8 and 32.8 degrees, 0.02 at 30.4-31.2 and
0.01 at 31.7; the other cases move by about a degree either way. The bound is a loose
one: the worst mean ratio is the same (0.753-0.756) in all these runs and in the compass
search's, the dihedral angle of the worst cell is what it leaves free."""
LINE_STEPS = np.array([2.0, 1.0, 0.5, 0.25, 0.125])
"""Step lengths tried along the direction, in units of the vertex's step (which follows
the last accepted step: 1.5 times its length)."""
SLIDE_STEPS = np.array([1.0, 0.5, 0.25])
"""Vertices on Gamma: fractions of the best step along the tangent line that are projected
onto Gamma and rated exactly."""
SLIDES = 6
"""Vertices on Gamma also try this many tangent directions at their step (projected), as
the compass search did: the projected gradient alone leaves the coarse torus on BCC about
a degree lower."""
COMPASS = 8
"""Inside vertices that gain nothing along their direction (a kink of three or more worst
tetrahedra, where the weighted sum is no ascent direction) try this many directions of a
turned Fibonacci sphere (:func:`_tetrahedron.directions`)."""
COMPASS_STEPS = np.array([1.0, 1.0 / 3.0])
"""Steps of those directions, in units of the vertex's step."""
MIN_STEP = 2e-2
"""Smallest step, in units of ``h``."""


def line_rating(s: Float, L: Float, sig: Float, beta2: Float, t: Float) -> Float:
    """:func:`rating` of star entries at ``p + t d`` (``|d| = 1``).

    With ``u = p - g`` and ``n`` of :func:`_tetrahedron.star_faces` at ``t = 0``:
    ``s = u . n``, ``L = |u|^2 + lsq``, ``sig = d . n`` and ``beta2 = 2 d . u``; then
    ``s(t) = s + t sig`` and ``L(t) = L + t (beta2 + t)``. The arrays broadcast (entries
    along the last axis, steps or directions in front); -1 where ``s(t) <= 0``.
    """
    st = t * sig
    st += s
    den = beta2 + t
    den *= t
    den += L
    return _rating(st, den)


def _rating(s: Float, L: Float) -> Float:
    """``s^2 / L^3`` where ``s > 0`` (and the quotient positive), -1 elsewhere; ``L`` is
    overwritten."""
    r = L * L
    r *= L
    np.divide(s * s, r, out=r)
    r[~((s > 0.0) & (r > 0.0))] = -1.0
    return r


def rating(s: Float, L: Float) -> Float:
    """The relaxation's rating of star entries: the cube of the quality, ``s^2 / L^3``.

    The quality of :func:`_tetrahedron.star_quality` is ``cbrt(s)^2 / L``; its cube is an
    increasing function of it with neither a cube root nor a square root, so the worst
    tetrahedron of a star, or of a candidate, is found on ratings, and a cube root
    (:func:`rating_quality`) is taken once per star and candidate instead of once per
    tetrahedron and candidate (about 20 times fewer). -1 where ``s <= 0`` (not positively
    oriented). ``s`` scales like ``h^3`` and ``L`` like ``h^2``: no overflow or underflow
    for cells from 1e-50 to 1e50 in size.
    """
    return _rating(s, np.array(L, dtype=np.float64))


_MAGIC = np.uint64(0x2A9F7893782DA1CE)
_SCALE_UP, _SCALE_DOWN = 2.0**54, 2.0**-18


def cube_root(x: Float) -> Float:
    """Cube roots of positive finite ``x``, from IEEE operations only (a few ulps).

    numpy's ``cbrt`` differs between CPUs (a vectorised one where the CPU has AVX-512,
    the C library's elsewhere), and so would the relaxation's decisions at near ties. This
    one is the same on every machine, and the C kernels (:mod:`_compiled`) evaluate the same
    operations: an estimate from the exponent's bits divided by 3 (relative error below
    7 %), then three Halley steps ``t ((t^3 + 2x) / (2 t^3 + x))`` (cubic convergence: below
    1e-15 before rounding). Subnormal ``x`` is scaled by ``2^54`` first.
    """
    xs = np.array(x, dtype=np.float64)  # a copy
    small = np.flatnonzero(xs < _TINY)
    xs[small] *= _SCALE_UP
    t = (xs.view(np.uint64) // np.uint64(3) + _MAGIC).view(np.float64)
    x2 = xs + xs
    for _ in range(3):
        t3 = t * t
        t3 *= t
        num = t3 + x2
        t3 += t3
        t3 += xs
        num /= t3
        t *= num
    t[small] *= _SCALE_DOWN
    return t


def rating_quality(r: Float) -> Float:
    """The quality ``cbrt(r)`` of ratings ``r`` of :func:`rating` (-1 where ``r <= 0``, inf
    where ``r`` is)."""
    r = np.asarray(r, dtype=np.float64)
    q = np.where(r == np.inf, np.inf, -1.0)  # inf: no entries (a fill value)
    pos = (r > 0.0) & (r < np.inf)
    q[pos] = cube_root(r[pos])
    return q


def ascent_gradients(
    q: Float, qworst: Float, s: Float, L: Float, u: tuple, n: tuple
) -> tuple[Float, Float, Float]:
    """Weighted unit gradients of the near-worst star entries (zero for the others).

    ``grad q = q (2/3 n / s - 2 u / L)`` at entries of quality ``q`` (all valid: ``s > 0``)
    whose star's worst quality is ``qworst``; weight ``1 - (q - qworst) / NEAR_WORST`` where
    positive. Summed over a star they give its ascent direction.
    """
    ux, uy, uz = u
    nx, ny, nz = n
    a, b = (2.0 / 3.0) / s, 2.0 / L
    gx, gy, gz = a * nx - b * ux, a * ny - b * uy, a * nz - b * uz
    gn = np.sqrt(gx * gx + gy * gy + gz * gz)
    wt = 1.0 - (q - qworst) / NEAR_WORST
    wt = np.where((wt > 0.0) & (gn > 0.0), wt / np.where(gn > 0.0, gn, 1.0), 0.0)
    return wt * gx, wt * gy, wt * gz


_K15 = (4.0 * 2.0 ** (-2.0 / 3.0) / tet.TARGET_MEAN_RATIO) ** 1.5
_TINY = np.finfo(np.float64).tiny


def star_terms(
    yc: tuple[Float, Float, Float], ip: np.ndarray, ia: np.ndarray, ib: np.ndarray, ic: np.ndarray
) -> tuple[tuple[Float, Float, Float], tuple[Float, Float, Float], Float, Float, Float]:
    """``u = p - g``, ``n``, ``lsq``, ``s`` and ``L`` of star entries ``(p, a, b, c)``.

    The terms of :func:`_tetrahedron.star_faces` and :func:`_tetrahedron.star_quality`
    (same scalings; ``g`` the facet's centroid, ``s = u . n``, ``L = |u|^2 + lsq``, the
    quality ``cbrt(s)^2 / L`` where ``s > 0``) for the vertices ``ip`` and facets
    ``(ia, ib, ic)`` of coordinates ``yc = (x, y, z)``, computed on separate coordinate
    arrays relative to ``a`` (``u = (p - a) - (ab + ac) / 3``): about half the array passes
    and none of the ``(n, 3)`` gathers and stacks of those two.
    """
    X, Y, Z = yc
    ax, ay, az = X[ia], Y[ia], Z[ia]
    bx, by, bz = X[ib] - ax, Y[ib] - ay, Z[ib] - az  # ab
    cx, cy, cz = X[ic] - ax, Y[ic] - ay, Z[ic] - az  # ac
    nx = (bz * cy - by * cz) * _K15  # -k^(3/2) ab x ac
    ny = (bx * cz - bz * cx) * _K15
    nz = (by * cx - bx * cy) * _K15
    # 4/9 (|ab|^2 + |ac|^2 + |ac - ab|^2) = 8/9 (|ab|^2 + |ac|^2 - ab . ac), no cancellation
    lsq = bx * bx + by * by + bz * bz + cx * cx + cy * cy + cz * cz
    lsq -= bx * cx + by * cy + bz * cz
    lsq *= 8.0 / 9.0
    np.maximum(lsq, _TINY, out=lsq)
    bx += cx
    by += cy
    bz += cz  # ab + ac = 3 (g - a)
    ux = X[ip] - ax - bx / 3.0
    uy = Y[ip] - ay - by / 3.0
    uz = Z[ip] - az - bz / 3.0
    s = ux * nx + uy * ny + uz * nz  # k^(3/2) 6 V
    L = ux * ux + uy * uy + uz * uz + lsq
    return (ux, uy, uz), (nx, ny, nz), lsq, s, L


def _compiled_colours(kernels: Any, csub: Int, priority: Float) -> tuple[Int, tuple]:
    """:func:`vertex_colours_graph` on one rank, and the star entries of :class:`_TetStars`
    sorted by colour, vertex and cell (``dvr_colour``: the same colours and order, from
    counting sorts instead of the pairs' sort and the entries' ``argsort``)."""
    ffi = kernels.ffi
    m, k = len(priority), len(csub)
    csub = np.ascontiguousarray(csub, dtype=np.int64)
    n = int(np.count_nonzero(csub >= 0))
    order = np.argsort(-priority).astype(np.int64)
    colour = np.empty(m, dtype=np.int64)
    ecell, ecorner = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    cfirst = np.full(k, -1, dtype=np.int64)
    scratch = [np.empty(size, dtype=np.int64) for size in (m + 1, n, m + 1, 3 * n, m, m, m + 1)]
    ncol = kernels.lib.dvr_colour(
        pointer(ffi, csub, "int64_t"), k, m,
        pointer(ffi, np.ascontiguousarray(priority, dtype=np.float64), "double"),
        pointer(ffi, order, "int64_t"), pointer(ffi, colour, "int64_t"),
        *(pointer(ffi, a, "int64_t") for a in scratch), pointer(ffi, ecell, "int64_t"),
        pointer(ffi, ecorner, "int64_t"), pointer(ffi, cfirst, "int64_t"),
    )  # fmt: skip
    if ncol < 0:
        raise RuntimeError(f"vertex colouring: more than {MAX_COLOURS} colours needed")
    return colour, (ecell, ecorner, cfirst[cfirst >= 0])


def _compass_directions(turn: int, frame: RelaxFrame | None) -> Float:
    """The :data:`COMPASS` directions of a visit (:func:`_tetrahedron.directions`), in
    world coordinates (C-contiguous); cached without a frame."""
    if frame is not None:
        return np.ascontiguousarray(frame.directions(tet.directions(COMPASS, turn)))
    return _world_directions(turn)


@functools.lru_cache(maxsize=1024)
def _world_directions(turn: int) -> Float:
    d = np.ascontiguousarray(tet.directions(COMPASS, turn), dtype=np.float64)
    d.flags.writeable = False
    return d


def _segment_min(v: Float, starts: Int) -> Float:
    """Minimum of each segment of the last axis."""
    return np.minimum.reduceat(v, starts, axis=-1) if len(starts) else v[..., :0]


def relax_tetrahedra(
    comm: MPI.Comm,
    imv: IndexMap,
    onto_gamma: Callable[[Float], tuple[Float, Float]],
    x0: Float,
    xp: Float,
    y: Float,
    cells: Int,
    movable: Bool,
    on_gamma: Bool,
    normal: Float,
    phi: Float,
    h: Float,
    sweeps: int | None = None,
    frame: RelaxFrame | None = None,
) -> Relaxation:
    """:func:`~dolfinx_universal.conforming.relax.relax_vertices` for tetrahedra: the
    directional relaxation (collective; same arguments, points ``(n, 3)``)."""
    y0, y, xp = y, y.copy(), xp.copy()
    if sweeps is None:
        sweeps = SWEEPS
    sub = SubVertices(imv, np.flatnonzero(movable))
    verts = sub.vertices
    m = len(verts)
    local = np.full(len(y), -1, dtype=np.int64)
    local[verts] = np.arange(m)
    csub = local[cells]
    priority = vertex_priority(x0[verts], frame)
    kernels = relax_kernels() if sub.map is None else None  # one rank: the C kernels
    if kernels is None:
        colour, entries = vertex_colours_graph(sub, csub, priority), None
    else:
        colour, entries = _compiled_colours(kernels, csub, priority)
    ncol = comm.allreduce(int(colour.max(initial=-1)) + 1, op=MPI.MAX)
    stars = _TetStars(y, cells, csub, colour, ncol, verts, on_gamma, h, kernels, entries)
    ev, cell_idx = stars.ev, stars.cell_idx
    bounds = np.searchsorted(colour[ev], np.arange(ncol + 1))
    groups = [np.flatnonzero(colour == k) for k in range(ncol)]
    search = _Directional(comm, sub, onto_gamma, stars, normal, on_gamma, h, frame)
    todo = np.ones(m, dtype=bool)
    num_moves, done = 0, 0
    for sweep in range(sweeps):
        changed = np.zeros(len(cells), dtype=bool)  # the cells a move changed in this sweep
        if sub.map is not None:
            todo = sub.reduce(todo.astype(np.float64), "max") > 0
        if not comm.allreduce(bool(todo[: sub.size_local].any()), op=MPI.LOR):
            break
        moves = 0
        again = np.zeros(m, dtype=bool)
        for k in range(ncol):
            S = groups[k][todo[groups[k]]]
            if not comm.allreduce(len(S) > 0, op=MPI.LOR):
                continue
            lo, hi = bounds[k], bounds[k + 1]
            if kernels is not None:  # (again: set at the movers and their neighbours)
                moves += search.visit_compiled(S, sweep * ncol + k, again)
                continue
            E = lo + np.flatnonzero(todo[ev[lo:hi]])
            win = search.visit(S, E, sweep * ncol + k, changed)
            again[win] = True
            moves += int(np.count_nonzero(win < sub.size_local))
        # The neighbours of the vertices moved in this sweep are worked on again.
        if kernels is None:
            again[ev[changed[cell_idx]]] = True
        todo = again
        done = sweep + 1
        moves = comm.allreduce(moves, op=MPI.SUM)
        num_moves += moves
        if moves == 0:
            break
    gamma_v = on_gamma[verts]
    slid_v = verts[gamma_v]
    slid_v = slid_v[np.any(y[slid_v] != y0[slid_v], axis=1)]
    xp[slid_v] = y[slid_v] + phi[slid_v, None] * search.nrm[slid_v]
    moved = np.any(y != x0, axis=1)
    return Relaxation(y, xp, moved, num_moves, done)


class _TetStars:
    """The tetrahedra around the movable vertices as star entries, with their qualities.

    One entry per (movable vertex ``p``, tetrahedron of ``p``) with the opposite facet
    ``(a, b, c)`` ordered so that ``(p, a, b, c)`` is positively oriented while ``p`` stays
    on the cell's side, sorted by colour and vertex: each colour is a slice, each vertex a
    segment of it. Degenerate tetrahedra (no orientation to keep) rate -1. The quality of
    each tetrahedron (:attr:`rcell`, its :func:`rating`) is computed once here (from one of
    its entries), then set by the move that changes it. Edges of Gamma_h (both ends on
    Gamma) may not grow beyond
    :data:`~dolfinx_universal.conforming.relax_common.GAMMA_EDGE_MAX` ``h`` (or their length
    after ``M_h``, if longer): one row per (vertex on Gamma, neighbour on Gamma), sorted by the
    vertex. On one rank with the C kernels (``kernels``), ``entries`` are the sorted entries
    of :func:`_compiled_colours`.
    """

    def __init__(
        self,
        y: Float,
        cells: Int,
        csub: Int,
        colour: Int,
        ncol: int,
        verts: Int,
        on_gamma: Bool,
        h: Float,
        kernels: Any = None,
        entries: tuple | None = None,
    ) -> None:
        m = len(verts)
        self.y = y  # the relaxation's current positions (moves write into it)
        if entries is None:
            cell_idx, corner = np.nonzero(csub >= 0)  # sorted by cell
            ev = csub[cell_idx, corner]
            key = colour[ev] * max(m, 1) + ev
            if (ncol + 1) * max(m, 1) * max(len(cells), 1) < 2**62:  # unique keys: faster
                order = np.argsort(key * len(cells) + cell_idx)
            else:
                order = np.argsort(key, kind="stable")
            inv = np.empty_like(order)
            inv[order] = np.arange(len(order))
            first = inv[np.flatnonzero(np.diff(cell_idx, prepend=-1))]  # its first corner's
            cell_idx, corner, ev = cell_idx[order], corner[order], ev[order]
        else:  # sorted by _compiled_colours
            cell_idx, corner, first = entries
            ev = csub[cell_idx, corner]
        # The facet opposite each entry's vertex, by flat index (no (cells, 4, 3) copy).
        flat_cells = np.ascontiguousarray(cells, dtype=np.int64).reshape(-1)
        base = 4 * cell_idx
        f0, f1, f2 = (flat_cells[base + tet.FACETS[:, i][corner]] for i in range(3))
        self.pv = verts[ev].astype(np.int64)
        # y's coordinates, for the numpy code (the C kernels read y)
        self.yc = (y[:, 0].copy(), y[:, 1].copy(), y[:, 2].copy()) if kernels is None else None
        self.f0, self.f1, self.f2 = f0, f1, f2
        self.cell_idx, self.ev = cell_idx, ev
        self.rcell = np.full(len(cells), -1.0)
        self.kernels = kernels
        self._orient(first, len(cells))
        # The caps of the edges of Gamma_h: entries at a vertex on Gamma, facet corners on it.
        g = np.flatnonzero(on_gamma[self.pv])
        gv = np.concatenate([ev[g]] * 3)
        gw = np.concatenate([f0[g], f1[g], f2[g]])
        both = on_gamma[gw]
        key = np.sort(gv[both] * len(y) + gw[both])
        key = key[np.diff(key, prepend=-1) != 0]
        self.cap_v, self.cap_w = key // len(y), key % len(y)
        length = np.sqrt(((y[verts[self.cap_v]] - y[self.cap_w]) ** 2).sum(axis=1))
        hmax_e = np.maximum(h[verts[self.cap_v]], h[self.cap_w])
        self.cap_len2 = (np.maximum(GAMMA_EDGE_MAX * hmax_e, length) * (1.0 + TIE)) ** 2
        self.cap_ptr = np.searchsorted(self.cap_v, np.arange(m + 1))  # each vertex's rows
        if self.kernels is not None:
            self._bind(self.kernels.ffi, m, csub)

    def _orient(self, first: Int, k: int) -> None:
        """The orientation of each cell from one entry's 6 V, the sign of ``s`` (entries
        ``first``, one per cell): the entries of negatively oriented cells take their facet
        the other way round, those of flat ones are marked :attr:`flat`; and the cells'
        ratings (:attr:`rcell`)."""
        f0, f1, f2, cell_idx = self.f0, self.f1, self.f2, self.cell_idx
        if self.kernels is not None:  # dvr_orient: the same operations
            ffi = self.kernels.ffi
            self.flat = np.empty(len(cell_idx), dtype=bool)
            self.kernels.lib.dvr_orient(
                pointer(ffi, self.y, "double"), pointer(ffi, self.pv, "int64_t"),
                pointer(ffi, f0, "int64_t"), pointer(ffi, f1, "int64_t"),
                pointer(ffi, f2, "int64_t"), pointer(ffi, cell_idx, "int64_t"),
                pointer(ffi, np.ascontiguousarray(first, dtype=np.int64), "int64_t"),
                len(first), len(cell_idx), k, _K15,
                pointer(ffi, self.flat.view(np.uint8), "uint8_t"),
                pointer(ffi, self.rcell, "double"),
            )  # fmt: skip
            return
        _, _, _, s, L = self.terms(first)
        orient = np.zeros(k)
        orient[cell_idx[first]] = np.sign(s)
        eo = orient[cell_idx]
        neg = np.flatnonzero(eo < 0)
        f1[neg], f2[neg] = f2[neg], f1[neg]
        self.flat = eo == 0  # no orientation to keep: rated -1 whatever the position
        turned = np.flatnonzero(s < 0.0)  # rated again, their facets turned
        if len(turned):
            _, _, _, s[turned], L[turned] = self.terms(first[turned])
        r = rating(s, L)
        r[self.flat[first]] = -1.0
        self.rcell[cell_idx[first]] = r

    def _bind(self, ffi: Any, m: int, csub: Int) -> None:
        """The C kernels' arguments that stay the same (the arrays written in place: the
        positions, the ratings)."""
        i64 = np.int64
        self.vfirst = np.zeros(m, dtype=i64)
        starts = np.flatnonzero(np.diff(self.ev, prepend=-1))
        self.vfirst[self.ev[starts]] = starts  # each vertex's entries are consecutive
        self.vcount = np.bincount(self.ev, minlength=m).astype(i64)
        self.stride = max(int(self.vcount.max(initial=0)), 1)
        self.scratch = np.empty(9 * self.stride)
        self._k = {
            name: np.ascontiguousarray(a, dtype=i64)
            for name, a in (("pv", self.pv), ("f0", self.f0), ("f1", self.f1), ("f2", self.f2),
                            ("cell_idx", self.cell_idx), ("cap_ptr", self.cap_ptr),
                            ("cap_w", self.cap_w), ("csub", csub))
        }  # fmt: skip
        self._k["flat"] = self.flat.view(np.uint8)
        self._k["cap_len2"] = np.ascontiguousarray(self.cap_len2, dtype=np.float64)
        types = {"flat": "uint8_t", "cap_len2": "double"}
        self.p = {n: pointer(ffi, a, types.get(n, "int64_t")) for n, a in self._k.items()}
        for name, a in (("y", self.y), ("rcell", self.rcell), ("scratch", self.scratch)):
            self.p[name] = pointer(ffi, a, "double")
        self.p["vfirst"] = pointer(ffi, self.vfirst, "int64_t")
        self.p["vcount"] = pointer(ffi, self.vcount, "int64_t")

    def terms(self, E: Int) -> tuple:
        """:func:`star_terms` of the entries ``E`` at the current positions."""
        assert self.yc is not None
        return star_terms(self.yc, self.pv[E], self.f0[E], self.f1[E], self.f2[E])


class _Directional:
    """The directional search of :func:`relax_tetrahedra`: one visit of a colour's vertices.

    Each vertex to work on (its worst tetrahedron below :data:`ACTIVE_BELOW`) takes its
    ascent direction, the best of :data:`LINE_STEPS` along it, the compass where it is stuck
    (inside vertices) or projected slides (vertices on Gamma), and moves if that beats
    staying by more than ``TIE``; its step follows the accepted one.
    """

    def __init__(
        self,
        comm: MPI.Comm,
        sub: SubVertices,
        onto_gamma: Callable[[Float], tuple[Float, Float]],
        stars: _TetStars,
        normal: Float,
        on_gamma: Bool,
        h: Float,
        frame: RelaxFrame | None = None,
    ) -> None:
        self.comm, self.sub, self.onto_gamma, self.stars = comm, sub, onto_gamma, stars
        self.frame = frame
        verts = sub.vertices
        self.gamma_v = on_gamma[verts]
        self.nrm = normal.copy()  # normals at the current positions of the vertices on Gamma
        self.step = INITIAL_STEP * h[verts]
        self.hmax = MAX_STEP * h[verts]
        self.hmin = MIN_STEP * h[verts]
        self.rowof = np.zeros(len(verts), dtype=np.int64)  # scratch: the row of each vertex
        self._c: dict[str, np.ndarray] = {}  # the compiled visit's buffers
        self._cp: dict[str, Any] = {}

    def _rows(self, S: Int, at: Int | slice, vals: Float, op: str, fill: float = np.inf) -> Float:
        """Per-vertex values ``vals`` at rows ``at`` of ``S`` (``fill`` elsewhere), reduced
        over the ranks with ``op``: one row per vertex of ``S``."""
        out = np.full((len(S),) + vals.shape[1:], fill)
        out[at] = vals
        return self.sub.reduce_rows(S, out, op)

    def visit(self, S: Int, E: Int, turn: int, changed: Bool) -> Int:
        """Work on the vertices ``S`` of one colour, whose entries are ``E`` (collective):
        move those that gain, mark the cells they change in ``changed``, return them.
        ``turn`` numbers the visit (it turns the compass directions)."""
        st, ev, cell_idx = self.stars, self.stars.ev, self.stars.cell_idx
        # The worst tetrahedron of each vertex's star (per row of S).
        vE = ev[E]
        self.rowof[S] = np.arange(len(S))
        rE = self.rowof[vE]
        starts = np.flatnonzero(np.diff(rE, prepend=-1))
        rcE = st.rcell[cell_idx[E]]  # the entries' ratings
        rv = self._rows(S, rE[starts], _segment_min(rcE, starts), "min")
        work = (rv < _ACTIVE_RATING) & (rv > 0.0)
        # Only the vertices to work on and their entries, from here (rows renumbered).
        keep = work[rE]
        E, S, q0 = E[keep], S[work], rating_quality(rv[work])
        rE = (np.cumsum(work) - 1)[rE[keep]]
        v = _Visit(S, E, q0, vE[keep], rE, st.terms(E), rcE[keep])
        self._direction(v)
        self._line(v)
        stuck = ~v.gain & ~self.gamma_v[S]
        if self.comm.allreduce(bool(stuck.any()), op=MPI.LOR) and len(COMPASS_STEPS):
            self._compass(v, stuck, turn)
        gi = np.flatnonzero(self.gamma_v[S] & (v.dn > 0.0))
        if self.comm.allreduce(len(gi) > 0, op=MPI.LOR):
            self._slides(v, gi, turn)
        return self._apply(v, changed)

    def visit_compiled(self, S: Int, turn: int, again: Bool) -> int:
        """:meth:`visit` on one rank with the C kernels (``dvr_visit``, the projection of
        the slides' candidates, ``dvr_slides``): the same moves, bitwise; ``again`` is set
        at the vertices that moved and at their neighbours. Returns the number of moves."""
        st = self.stars
        assert st.kernels is not None
        ffi, lib, p = st.kernels.ffi, st.kernels.lib, st.p
        if not self._c:
            self._bind(ffi)
        c, cp = self._c, self._cp
        ns = len(SLIDE_STEPS) + SLIDES
        dirs = _compass_directions(turn, self.frame)
        ag = pointer(ffi, again.view(np.uint8), "uint8_t")
        if self.frame is None:  # the slides' candidates in C
            theta = tet.tangent_angles(SLIDES, turn)
            tcos, tsin = np.cos(theta), np.sin(theta)
            gpc, gtg = cp["gpc"], cp["gtg"]
        else:
            tcos = tsin = np.zeros(0)
            gpc = gtg = ffi.NULL
        S = np.ascontiguousarray(S, dtype=np.int64)
        nG = ffi.new("int64_t *")
        moves = lib.dvr_visit(
            p["y"], p["pv"], p["f0"], p["f1"], p["f2"], p["cell_idx"],
            p["csub"], p["rcell"], p["vfirst"], p["vcount"], cp["gamma"], cp["nrm"],
            cp["step"], cp["hmin"], cp["hmax"], pointer(ffi, S, "int64_t"), len(S),
            cp["line"], len(LINE_STEPS), pointer(ffi, dirs, "double"), len(dirs),
            cp["csteps"], len(COMPASS_STEPS), cp["slides"], len(SLIDE_STEPS),
            pointer(ffi, tcos, "double"), pointer(ffi, tsin, "double"), len(tcos), _K15, TIE,
            NEAR_WORST, _ACTIVE_RATING, p["scratch"], st.stride, ag, cp["G"], cp["gdv"],
            cp["gtb"], cp["gq0"], gpc, gtg, nG,
        )  # fmt: skip
        if moves < 0:
            raise ValueError("dvr_visit: more than 64 candidates per vertex")
        ng = int(nG[0])
        if not ng:
            return int(moves)
        G = c["G"][:ng]
        if self.frame is None:
            pc = c["gpc"][:ng]
            pp, pn = collective_call(
                self.comm, "projection onto Gamma", self.onto_gamma, pc.reshape(-1, 3)
            )
            tg = c["gtg"][:ng]
        else:
            pp, pn, tg = self.slide_candidates(G, c["gdv"][:ng], c["gtb"][:ng], turn)
        pp, pn, tg = (np.ascontiguousarray(a, dtype=np.float64) for a in (pp, pn, tg))
        slid = lib.dvr_slides(
            p["y"], p["pv"], p["f0"], p["f1"], p["f2"], p["cell_idx"],
            p["csub"], p["flat"], p["rcell"], p["vfirst"], p["vcount"], cp["nrm"],
            cp["step"], cp["hmin"], cp["hmax"], p["cap_ptr"], p["cap_w"], p["cap_len2"],
            cp["G"], ng, cp["gq0"], pointer(ffi, pp, "double"), pointer(ffi, pn, "double"),
            pointer(ffi, tg, "double"), ns, _K15, TIE, p["scratch"], st.stride, ag,
        )  # fmt: skip
        if slid < 0:
            raise ValueError("dvr_slides: more than 64 candidates per vertex")
        return int(moves + slid)

    def _bind(self, ffi: Any) -> None:
        """The compiled visit's buffers (one row per movable vertex) and pointers."""
        n, ns = len(self.step), len(SLIDE_STEPS) + SLIDES
        self._c = {
            "G": np.empty(n, dtype=np.int64),
            "gdv": np.empty((n, 3)),
            "gtb": np.empty(n),
            "gq0": np.empty(n),
            "gpc": np.empty((n, ns, 3)),
            "gtg": np.empty((n, ns)),
        }
        self._cp = {name: pointer(ffi, a, "double") for name, a in self._c.items() if name != "G"}
        self._cp["G"] = pointer(ffi, self._c["G"], "int64_t")
        self._cp["gamma"] = pointer(ffi, self.gamma_v.view(np.uint8), "uint8_t")
        for name in ("nrm", "step", "hmin", "hmax"):
            self._cp[name] = pointer(ffi, getattr(self, name), "double")
        for name, a in (("line", LINE_STEPS), ("csteps", COMPASS_STEPS), ("slides", SLIDE_STEPS)):
            self._cp[name] = pointer(ffi, a, "double")

    def _direction(self, v: _Visit) -> None:
        """The ascent direction of each star: the near-worst entries' unit gradients,
        weighted, summed over the ranks; in the tangent plane for vertices on Gamma."""
        (ux, uy, uz), (nx, ny, nz), _, s, L = v.terms
        rE, S = v.rE, v.S
        q = v.q0 + NEAR_WORST  # the ratings below q^3: qualities below q0 + NEAR_WORST
        w = q * q
        w *= q
        nw = np.flatnonzero(v.r < w[rE])
        wg = ascent_gradients(
            rating_quality(v.r[nw]),
            v.q0[rE[nw]],
            s[nw],
            L[nw],
            (ux[nw], uy[nw], uz[nw]),
            (nx[nw], ny[nw], nz[nw]),
        )
        dv = np.empty((len(S), 3))
        for i, wgi in enumerate(wg):
            dv[:, i] = np.bincount(rE[nw], weights=wgi, minlength=len(S))
        dv = self._rows(S, slice(None), dv, "sum", 0.0)
        gs = np.flatnonzero(self.gamma_v[S])
        if len(gs):  # in the tangent plane
            nn = self.nrm[self.sub.vertices[S[gs]]]
            d = dv[gs, 0] * nn[:, 0] + dv[gs, 1] * nn[:, 1] + dv[gs, 2] * nn[:, 2]
            dv[gs] -= d[:, None] * nn
        dvx, dvy, dvz = dv[:, 0], dv[:, 1], dv[:, 2]
        v.dn = np.sqrt(dvx * dvx + dvy * dvy + dvz * dvz)
        dv /= np.where(v.dn > 0.0, v.dn, 1.0)[:, None]
        v.dv = dv

    def _line(self, v: _Visit) -> None:
        """The worst quality along each direction at :data:`LINE_STEPS` times the step; the
        first step within ``TIE`` of the best, a gain if it beats staying by ``> TIE``."""
        (ux, uy, uz), (nx, ny, nz), _, s, L = v.terms
        rE, S, dv = v.rE, v.S, v.dv
        dx, dy, dz = dv[:, 0][rE], dv[:, 1][rE], dv[:, 2][rE]
        sig = dx * nx + dy * ny + dz * nz
        beta2 = dx * ux + dy * uy + dz * uz
        beta2 *= 2.0
        t = LINE_STEPS[:, None] * self.step[v.vE][None]  # (steps, entries)
        rt = line_rating(s, L, sig, beta2, t)  # (caps: rated below, on Gamma)
        qs = rating_quality(self._rows(S, rE[v.starts], _segment_min(rt, v.starts).T, "min"))
        best = np.argmax(qs >= qs.max(axis=1, initial=-np.inf)[:, None] - TIE, axis=1)
        v.qb = qs[np.arange(len(S)), best]
        v.tb = LINE_STEPS[best] * self.step[S]
        v.gain = (v.qb > v.q0 + TIE) & (v.dn > 0.0)
        v.new = self.stars.y[self.sub.vertices[S]] + v.tb[:, None] * dv
        # The entries' ratings at each vertex's chosen candidate.
        v.rnew = rt[best[rE], np.arange(len(v.E))]

    def _compass(self, v: _Visit, stuck: Bool, turn: int) -> None:
        """Inside vertices stuck along their direction (a kink of three or more worst
        tetrahedra): :data:`COMPASS` directions at :data:`COMPASS_STEPS` times the step."""
        (ux, uy, uz), (nx, ny, nz), _, s, L = v.terms
        rE, S = v.rE, v.S
        cs = np.flatnonzero(stuck[rE])
        dirs = _compass_directions(turn, self.frame)
        sx, sy, sz = (a[cs] for a in (ux, uy, uz))
        sig = dirs[:, 0, None] * nx[cs] + dirs[:, 1, None] * ny[cs] + dirs[:, 2, None] * nz[cs]
        beta2 = 2.0 * (dirs[:, 0, None] * sx + dirs[:, 1, None] * sy + dirs[:, 2, None] * sz)
        tc = COMPASS_STEPS[:, None, None] * self.step[v.vE[cs]][None, None]  # (ns, 1, n)
        qc = line_rating(s[cs], L[cs], sig[None], beta2[None], tc)
        qc = qc.reshape(COMPASS * len(COMPASS_STEPS), len(cs))  # (the same on all ranks)
        rc = rE[cs]
        sc = np.flatnonzero(np.diff(rc, prepend=-1))
        qsc = rating_quality(self._rows(S, rc[sc], _segment_min(qc, sc).T, "min"))
        bc = np.argmax(qsc >= qsc.max(axis=1, initial=-np.inf)[:, None] - TIE, axis=1)
        qbc = qsc[np.arange(len(S)), bc]
        take = stuck & (qbc > v.q0 + TIE)
        jc, ic = np.divmod(bc, COMPASS)
        tcb = COMPASS_STEPS[jc] * self.step[S]
        v.gain |= take
        v.new[take] = self.stars.y[self.sub.vertices[S[take]]] + (tcb[:, None] * dirs[ic])[take]
        v.tb[take] = tcb[take]
        v.qb[take] = qbc[take]
        tk = take[rc]
        v.rnew[cs[tk]] = qc[bc[rc[tk]], np.flatnonzero(tk)]

    def slide_candidates(self, G: Int, dv: Float, tb: Float, turn: int) -> tuple:
        """The candidates of the vertices on Gamma ``G`` (rows of the movable vertices) with
        directions ``dv`` and best steps ``tb`` along them: :data:`SLIDE_STEPS` of the step
        along the direction and :data:`SLIDES` tangent directions at the vertex's step,
        projected onto Gamma (collective). Returns the points and normals ``(len(G), ns,
        3)`` and the steps ``(len(G), ns)``."""
        verts = self.sub.vertices
        yG = self.stars.y[verts[G]]
        tg = tb[:, None] * SLIDE_STEPS[None]
        pc = yG[:, None, :] + tg[..., None] * dv[:, None, :]
        if SLIDES:  # and a compass in the tangent plane at the current step
            if self.frame is None:
                td = tet.tangent_directions(self.nrm[verts[G]], SLIDES, turn)
            else:  # built on the normals in the frame, turned back
                R = self.frame.rotation
                td = self.frame.directions(
                    tet.tangent_directions(self.nrm[verts[G]] @ R, SLIDES, turn)
                )
            pc = np.concatenate([pc, yG[:, None, :] + self.step[G, None, None] * td], axis=1)
            tg = np.concatenate([tg, np.repeat(self.step[G, None], SLIDES, axis=1)], axis=1)
        ns = pc.shape[1]
        pp, pn = collective_call(
            self.comm, "projection onto Gamma", self.onto_gamma, pc.reshape(-1, 3)
        )
        return pp.reshape(len(G), ns, 3), pn.reshape(len(G), ns, 3), tg

    def _slides(self, v: _Visit, gi: Int, turn: int) -> None:
        """Vertices on Gamma (rows ``gi`` of the visit): the candidates of
        :meth:`slide_candidates`, rated exactly; a slide may not stretch an edge of Gamma_h
        beyond its cap."""
        st = self.stars
        (ux, uy, uz), (nx, ny, nz), lsq, _, _ = v.terms
        rE, S, E = v.rE, v.S, v.E
        G = S[gi]
        pp, pn, tg = self.slide_candidates(G, v.dv[gi], v.tb[gi], turn)
        ns = pp.shape[1]
        gpos = np.full(len(S), -1, dtype=np.int64)
        gpos[gi] = np.arange(len(G))
        eg = np.flatnonzero(gpos[rE] >= 0)
        rg = gpos[rE[eg]]
        pcx, pcy, pcz = (np.ascontiguousarray(pp[..., i].T) for i in range(3))
        ip = st.pv[E[eg]]
        yc = st.yc
        assert yc is not None
        # The entries' facets (tet.star_faces: centroid g = p - u, n, lsq), rated at the
        # candidates, laid out (ns, entries).
        face = tet.StarFaces(
            *(a[None] for a in (yc[0][ip] - ux[eg], yc[1][ip] - uy[eg], yc[2][ip] - uz[eg],
                                nx[eg], ny[eg], nz[eg], lsq[eg]))
        )  # fmt: skip
        rg_ = _rating(*tet.star_volume_terms(pcx[:, rg], pcy[:, rg], pcz[:, rg], face))
        rg_[:, st.flat[E[eg]]] = -1.0
        seg = np.flatnonzero(np.diff(rg, prepend=-1))
        rsg = np.full((len(G), ns), np.inf)
        if len(seg):
            rsg[rg[seg]] = _segment_min(rg_, seg).T
        # A slide may not stretch an edge of Gamma_h beyond its cap.
        cnt = st.cap_ptr[G + 1] - st.cap_ptr[G]
        cfirst = np.cumsum(cnt) - cnt
        ce = np.repeat(st.cap_ptr[G] - cfirst, cnt) + np.arange(cnt.sum())
        cr = np.repeat(np.arange(len(G)), cnt)
        w = st.cap_w[ce]
        dx, dy, dz = pcx[:, cr] - yc[0][w], pcy[:, cr] - yc[1][w], pcz[:, cr] - yc[2][w]
        long = dx * dx + dy * dy + dz * dz > st.cap_len2[ce]  # (ns, cap rows)
        has = np.flatnonzero(cnt > 0)
        if len(has):
            over = np.logical_or.reduceat(long, cfirst[has], axis=1)
            rsg[has] = np.where(over.T, -1.0, rsg[has])
        qsg = rating_quality(self._rows(G, slice(None), rsg, "min"))
        bg = np.argmax(qsg >= qsg.max(axis=1, initial=-np.inf)[:, None] - TIE, axis=1)
        rows = np.arange(len(G))
        v.qb[gi] = qsg[rows, bg]
        v.gain[gi] = v.qb[gi] > v.q0[gi] + TIE
        v.new[gi] = pp[rows, bg]
        v.tb[gi] = tg[rows, bg]
        slid = v.gain[gi]
        self.nrm[self.sub.vertices[G[slid]]] = pn[rows, bg][slid]
        v.rnew[eg] = rg_[bg[rg], np.arange(len(eg))]

    def _apply(self, v: _Visit, changed: Bool) -> Int:
        """Move the vertices that gain, set the qualities of their tetrahedra, and let the
        step follow the accepted one; return the movers."""
        st, verts, gain = self.stars, self.sub.vertices, v.gain
        win = v.S[gain]
        st.y[verts[win]] = v.new[gain]
        assert st.yc is not None
        for i in range(3):
            st.yc[i][verts[win]] = v.new[gain, i]
        moved_e = gain[v.rE]
        st.rcell[st.cell_idx[v.E[moved_e]]] = v.rnew[moved_e]
        changed[st.cell_idx[v.E[moved_e]]] = True
        self.step[win] = np.clip(1.5 * np.abs(v.tb[gain]), self.hmin[win], self.hmax[win])
        return win


class _Visit:
    """The arrays of one visit of :class:`_Directional` (the vertices ``S`` worked on, their
    entries ``E``, rows, star terms, and the candidate chosen so far)."""

    def __init__(self, S: Int, E: Int, q0: Float, vE: Int, rE: Int, terms: tuple, r: Float) -> None:
        self.S, self.E, self.q0, self.terms, self.r = S, E, q0, terms, r
        self.vE, self.rE = vE, rE  # each entry's vertex, and its row in S
        self.starts = np.flatnonzero(np.diff(self.rE, prepend=-1))
        self.dv = np.zeros((len(S), 3))
        self.dn = np.zeros(len(S))
        self.qb = np.zeros(len(S))
        self.tb = np.zeros(len(S))
        self.gain = np.zeros(len(S), dtype=bool)
        self.new = np.zeros((len(S), 3))
        self.rnew = np.zeros(len(E))  # the entries' ratings at the chosen candidate
