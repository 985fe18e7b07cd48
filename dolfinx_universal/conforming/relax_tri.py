"""Vertex relaxation of triangles: a compass search that raises the worst triangle of each star.

After ``M_h`` the triangles at Gamma are the worst of a universal mesh (Rangarajan & Lew
2014: minimum angles of about 21-23 degrees on equilateral backgrounds). Connectivity is
fixed, so quality can only be gained by moving vertices: each inside vertex of the band
moves freely, each vertex on Gamma slides along Gamma (candidates are moved onto Gamma by
:meth:`~dolfinx_universal.boundaries.base.Boundary.onto_gamma`: the closest-point map, or a
cheaper map onto Gamma where a boundary has one), to maximise the worst
:func:`shape_quality` (smallest angle and radius ratio) of the kept triangles around it.
This is the max-min (nonsmooth) vertex optimisation of optimisation-based smoothing
(Freitag & Ollivier-Gooch 1997; Amenta, Bern & Eppstein 1999), solved here by a compass
(pattern) search: a few directions and step lengths per vertex and sweep, the step growing
after a success and shrinking where no candidate helps. A move is accepted only if it
raises the vertex's worst incident quality (by more than a tolerance, :data:`TIE`) and
keeps every incident kept triangle positively oriented, so validity and the global minimum
of the quality never get worse. Among candidates that tie up to :data:`TIE` the first in a
fixed order wins, so that no decision hangs on rounding: the same domain given through
another parametrisation (a threefold propeller turned by 120 degrees) gives the same mesh
up to rounding.

The cost is kept down by working only where it pays: a vertex stops once its triangles
meet the targets with a margin (:data:`ACTIVE_BELOW`), or come within 10 % of its star's
in the background (:data:`ACTIVE_RATIO`), or its step has converged
(:data:`MIN_STEP`), the vertices on Gamma slide only in the first :data:`GAMMA_SWEEPS`
sweeps (each costs a projection onto Gamma), star qualities are recomputed only where a
corner moved, and colours without a working vertex are skipped.

Vertices that share a kept triangle never move together (the colours of
:func:`~dolfinx_universal.conforming.relax_common.vertex_colours`). A vertex's star may span
ranks: each rank rates the candidates on its owned triangles and a min-reduction over the
ranks gives every rank (owner and ghosts) the same ratings, hence the same move.

The inner loops (the ratings of the candidates, in one process the whole colour passes with
their decisions, the star minima, the candidates) run as C kernels compiled at first use
(:mod:`dolfinx_universal.core.compiled`, with the C compiler DOLFINx's forms need): bitwise the
ratings of the numpy code, which runs where no compiler is found. They cut the relaxation's
share of a moving update from about 55 % to under 30 %.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from dolfinx_universal.conforming.relax_common import (
    GAMMA_EDGE_MAX,
    INITIAL_STEP,
    MAX_STEP,
    TIE,
    Relaxation,
    RelaxFrame,
    SubVertices,
    vertex_colours_graph,
    vertex_priority,
)
from dolfinx_universal.core.arrays import Bool, Float, Int, any_rows, rot90
from dolfinx_universal.core.collective import collective_call
from dolfinx_universal.core.compiled import pointer, relax_kernels

if TYPE_CHECKING:
    from dolfinx.common import IndexMap

__all__ = ["relax_triangles", "shape_quality"]

DIRECTIONS = 8
"""Compass directions per vertex and sweep (rotated by the golden angle from sweep to sweep)."""
STEPS = (1.0, 1.0 / 3.0)
"""Step lengths tried along each direction, in units of the vertex's current step."""
GAMMA_STEPS = (1.0,)
"""Step lengths tried along Gamma (both ways) by the vertices on Gamma, as ``STEPS``."""
MIN_STEP = 1e-2
"""A vertex stops once its step falls below this, in units of ``h``: its compass search has
converged (a move of ``h / 100`` changes an angle by at most about half a degree)."""
SWEEPS = 12
"""Default number of sweeps over all colours."""
GAMMA_SWEEPS = 6
"""Sweeps in which the vertices on Gamma slide (each costs a projection onto Gamma, the
dearest step of a sweep; on the circle study sliding for all 12 sweeps gains 0-0.3 degrees
of minimum angle, at 10-20 % more cost)."""
ACTIVE_BELOW = 1.05
"""A vertex moves in a sweep only if a triangle around it has a :func:`shape_quality`
below this (1 at the targets, 1.3 for an equilateral triangle): vertices that meet the
targets with a margin of 5 % stop, so that after a few sweeps only the few vertices at the
worst triangles are still worked on (on the circle study 1.1 instead keeps every band
vertex busy for all sweeps, at twice the cost, for a minimum angle 1-2 degrees higher)."""
ACTIVE_RATIO = 0.9
"""A vertex moves in a sweep only if its worst triangle is also below this fraction of the
worst quality of its star in the background (before ``M_h``): a vertex stops once its star
is within 10 % of what the background offered there. On equilateral backgrounds (quality 1.30)
:data:`ACTIVE_BELOW` decides alone. Graded backgrounds have worse cells (0.93-1.10 on the
propeller demo's), and there the absolute targets kept almost every band vertex busy for
all sweeps for gains of no consequence: on the propeller demo (24 steps) 0.9 halves the
work (9.5e3 instead of 1.9e4 vertex visits per update) for the same smallest angle (29.36
degrees) and median (30.42 against 30.45 degrees); on 18 domains through ``mesh_domain``
(16 random domains, two circles) the extreme angles move by at most 0.4 degrees. (0.85
halves the work again, but costs some of those domains up to 1.6 degrees.)"""
TARGET_ANGLE = 40.0
"""Smallest angle (degrees) at which the angle term of :func:`shape_quality` is 1."""
TARGET_RADIUS_RATIO = 2.6
"""Circumradius / inradius at which the radius term of :func:`shape_quality` is 1."""
_ANGLE_SCALE = 1.0 / np.sin(np.radians(TARGET_ANGLE))
_RADIUS_SCALE = TARGET_RADIUS_RATIO / 2.0
_RADIUS_SCALE4 = 4.0 * _RADIUS_SCALE  # (the kernel's factor of cross^2, one double)
_GROW, _HOLD, _SHRINK = 1.5, 0.75, 0.4
"""Step factors of the compass search: after a move at the full step, after a move at a
shorter step, and where nothing helped."""


def shape_quality(p: Float, a: Float, b: Float, orientation: Float) -> Float:
    """Quality of triangles ``(p, a, b)`` against the relaxation's targets; -1 where inverted.

    ``min(sin(theta_min) / sin(40 deg), (2 r / R) / (2 / 2.6))``: each term is 1 at its
    target (smallest angle 40 degrees, circumradius / inradius ``R / r = 2.6``) and about
    1.3 for an equilateral triangle. The angle term alone leaves near-right triangles with
    a largest angle around 95 degrees; the radius ratio alone lets the smallest angle fall
    to 35 degrees; their minimum keeps both in check. With ``l`` the edge lengths and ``A``
    the area, ``sin(theta_min) = 2 A l_min / (l_0 l_1 l_2)`` (the smallest angle lies
    between the two longest edges) and ``2 r / R = 16 A^2 / ((l_0 + l_1 + l_2) l_0 l_1 l_2)``.

    Parameters
    ----------
    p, a, b
        Corners ``(..., 2)`` (broadcast together).
    orientation
        +1 or -1: the sign the signed area must have (``(...)``, broadcast).

    Returns
    -------
    The quality where ``orientation * area > 0``; -1 elsewhere, shape ``(...)``.
    """
    u, v = a - p, b - p
    ux, uy, vx, vy = u[..., 0], u[..., 1], v[..., 0], v[..., 1]
    cross = orientation * (ux * vy - uy * vx)  # 2 A
    lu, lv = ux * ux + uy * uy, vx * vx + vy * vy
    w = b - a
    lw = w[..., 0] ** 2 + w[..., 1] ** 2
    su, sv, sw = np.sqrt(lu), np.sqrt(lv), np.sqrt(lw)
    prod = su * sv * sw
    with np.errstate(divide="ignore", invalid="ignore"):
        angle = cross * np.minimum(np.minimum(su, sv), sw) / prod
        radius = 4.0 * cross * cross / ((su + sv + sw) * prod)
    q = np.minimum(angle * _ANGLE_SCALE, radius * _RADIUS_SCALE)
    return np.where((cross > 0) & (prod > 0), q, -1.0)


def _star_quality(
    px: Float, py: Float, ax: Float, ay: Float, bx: Float, by: Float, lab: Float
) -> Float:
    """:func:`shape_quality` of counter-clockwise triangles ``(p, a, b)`` (up to rounding).

    The same formulas on separate, broadcast coordinate arrays, with the length ``lab`` of
    the edge ``ab`` (which all candidates ``p`` of a star entry share) given: the kernel of
    the sweeps, about half the array passes of :func:`shape_quality`.
    """
    ux, uy, vx, vy = ax - px, ay - py, bx - px, by - py
    cross = ux * vy - uy * vx  # 2 A
    su, sv = np.sqrt(ux * ux + uy * uy), np.sqrt(vx * vx + vy * vy)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.minimum(
            cross * np.minimum(np.minimum(su, sv), lab) * _ANGLE_SCALE,
            cross * cross * _RADIUS_SCALE4 / (su + sv + lab),
        ) / (su * sv * lab)
    return np.where(cross > 0, q, -1.0)


def relax_triangles(
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
    *,
    sweeps: int | None = None,
    frame: RelaxFrame | None = None,
) -> Relaxation:
    """:func:`~dolfinx_universal.conforming.relax.relax_vertices` for triangles: the compass
    search (collective; same arguments, points ``(n, 2)``).

    Sweeps over the colours of
    :func:`~dolfinx_universal.conforming.relax_common.vertex_colours`; in each, every vertex of
    the colour with a triangle below :data:`ACTIVE_BELOW` and a step above :data:`MIN_STEP`
    tries :data:`DIRECTIONS` compass directions at :data:`STEPS` times its step (the vertices
    on Gamma, in the first :data:`GAMMA_SWEEPS` sweeps: both ways along Gamma at
    :data:`GAMMA_STEPS`) and takes the first candidate within :data:`TIE` of the best if
    that beats where it is by more than :data:`TIE`.
    """
    y0, y, xp = y, y.copy(), xp.copy()
    if sweeps is None:
        sweeps = SWEEPS
    sub = SubVertices(imv, np.flatnonzero(movable))
    verts = sub.vertices
    m = len(verts)
    local = np.full(len(y), -1, dtype=np.int64)
    local[verts] = np.arange(m)
    csub = local[cells]
    colour = vertex_colours_graph(sub, csub, vertex_priority(x0[verts], frame))
    ncol = comm.allreduce(int(colour.max(initial=-1)) + 1, op=MPI.MAX)
    stars = _Stars(y, cells, csub, colour, verts, on_gamma, h)
    ev = stars.ev
    bounds = np.searchsorted(colour[ev], np.arange(ncol + 1))
    groups = [
        (slice(bounds[k], bounds[k + 1]), np.flatnonzero(colour == k)) for k in range(ncol)
    ]  # each colour's entries, and its vertices (with or without entries on this rank)
    compass = _Compass(comm, sub, onto_gamma, y, normal, on_gamma, h, frame, x0)
    # A vertex is worked on below the targets and below what its background star offered.
    target = sub.reduce(ACTIVE_RATIO * stars.background_minima(x0, m), "min")
    np.minimum(target, ACTIVE_BELOW, out=target)
    num_moves, done, idle = 0, 0, 0
    changed = np.ones(len(y), dtype=bool)  # vertices moved since the star qualities were rated
    for sweep in range(sweeps):
        # Only vertices with a triangle below ACTIVE_BELOW move in this sweep ...
        star = stars.star_minima(changed, m)
        changed[:] = False
        # ... and whose compass search has not converged (step below MIN_STEP h).
        active = (sub.reduce(star, "min") < target) & (compass.step > compass.hmin)
        if sweep >= GAMMA_SWEEPS:  # the vertices on Gamma have had their sweeps
            active[compass.gamma] = False
        if not comm.allreduce(bool(active[: sub.size_local].any()), op=MPI.LOR):
            break
        live = np.zeros(ncol, dtype=bool)
        live[colour[active]] = True
        if sub.map is not None:
            flags = live.astype(np.int32)
            comm.Allreduce(MPI.IN_PLACE, flags, op=MPI.MAX)
            live = flags > 0
        compass.generate(active, sweep)
        if compass.kernels is not None and sub.map is None:  # the colour passes in C
            moves = compass.move_colours(np.flatnonzero(live), bounds, active, stars, changed)
        else:
            moves = 0
            for k in np.flatnonzero(live):
                e, S = groups[k]
                E = e.start + np.flatnonzero(active[ev[e]])
                win = compass.move(S[active[S]], E, stars)
                changed[verts[win]] = True
                moves += int(np.count_nonzero(win < sub.size_local))
        done = sweep + 1
        moves = comm.allreduce(moves, op=MPI.SUM)
        num_moves += moves
        idle = idle + 1 if moves == 0 else 0
        if idle >= 2:
            break
    slid = verts[compass.gamma]
    slid = slid[np.any(y[slid] != y0[slid], axis=1)]
    xp[slid] = y[slid] + phi[slid, None] * compass.nrm[slid]
    moved = any_rows(y != x0)
    return Relaxation(y, xp, moved, num_moves, done)


class _Stars:
    """The triangles around the movable vertices, as star entries, and their ratings.

    One entry per (movable vertex ``p``, triangle of ``p``) with the triangle's other
    corners ``a``, ``b`` in counter-clockwise order (so that the kernel rates ``(p, a, b)``),
    sorted by colour and vertex: each colour is a slice, each vertex a segment of it.
    Degenerate triangles (no orientation to keep) rate -1 whatever the candidate. Edges
    between two vertices on Gamma (the edges of Gamma_h) may not grow beyond
    :data:`GAMMA_EDGE_MAX` ``h`` (or their length after ``M_h``, if longer): the same cap seen
    from both ends, so that it always holds and the ratings stay those of the true
    triangles. ``y`` is the relaxation's array of current positions (moves write into it).
    """

    def __init__(
        self, y: Float, cells: Int, csub: Int, colour: Int, verts: Int, on_gamma: Bool, h: Float
    ) -> None:
        self.y = y
        cell_idx, corner = np.nonzero(csub >= 0)
        ev = csub[cell_idx, corner]
        # by colour, then vertex (one stable sort of one key: np.lexsort's order)
        order = np.argsort(colour[ev] * max(len(colour), 1) + ev, kind="stable")
        cell_idx, corner, ev = cell_idx[order], corner[order], ev[order]
        ea = cells[cell_idx, (corner + 1) % 3]
        eb = cells[cell_idx, (corner + 2) % 3]
        # The orientation of each cell with a movable vertex, once per cell.
        with_entries = np.zeros(len(cells), dtype=bool)
        with_entries[cell_idx] = True
        with_entries = np.flatnonzero(with_entries)
        c = cells[with_entries]
        y0, y1 = y[:, 0], y[:, 1]
        d1x, d1y = y0[c[:, 1]] - y0[c[:, 0]], y1[c[:, 1]] - y1[c[:, 0]]
        d2x, d2y = y0[c[:, 2]] - y0[c[:, 0]], y1[c[:, 2]] - y1[c[:, 0]]
        orient = np.zeros(len(cells))
        orient[with_entries] = np.sign(d1x * d2y - d1y * d2x)
        eo = orient[cell_idx]
        self.ea, self.eb = np.where(eo < 0, eb, ea), np.where(eo < 0, ea, eb)
        self.ev, self.verts = ev, verts
        self.pv = verts[ev]  # each entry's vertex (process-local)
        self.flat = eo == 0
        self.any_flat = bool(self.flat.any())
        pv = self.pv
        self.caps = []  # per opposite corner: the cap of each entry's edge p-corner, inf if none
        for corner_of in (self.ea, self.eb):
            cap = np.full(len(ev), np.inf)
            both = np.flatnonzero(on_gamma[pv] & on_gamma[corner_of])
            d = y[pv[both]] - y[corner_of[both]]
            length = np.hypot(d[..., 0], d[..., 1])  # as in rate(): the current position passes
            hmax_e = np.maximum(h[pv[both]], h[corner_of[both]])
            cap[both] = np.maximum(GAMMA_EDGE_MAX * hmax_e, length) * (1.0 + TIE)
            if len(both):
                self.caps.append((corner_of, cap))
        # Entries with a capped edge (either corner): rate() checks those only.
        self.capped = np.zeros(len(ev), dtype=bool)
        for _, cap in self.caps:
            self.capped |= cap < np.inf
        self.first = np.diff(ev, prepend=-1) != 0  # the first entry of each vertex's segment
        self.vstart = np.flatnonzero(self.first)
        self.qe = np.empty(len(ev))  # quality of each entry at the current positions
        self.kernels = relax_kernels()
        if self.kernels is not None:
            self._bind(self.kernels.ffi)

    def _bind(self, ffi: Any) -> None:
        """The C kernels' arguments that stay the same (``y`` is written in place)."""
        i64 = np.int64
        k = {
            "ea": np.ascontiguousarray(self.ea, dtype=i64),
            "eb": np.ascontiguousarray(self.eb, dtype=i64),
            "ev": np.ascontiguousarray(self.ev, dtype=i64),
            "pv": np.ascontiguousarray(self.pv, dtype=i64),
            "flat": self.flat.astype(np.uint8),
            "first": self.first.astype(np.uint8),
        }
        for corner, name in ((self.ea, "cap_a"), (self.eb, "cap_b")):
            k[name] = np.full(len(self.ev), np.inf)
            for corner_of, cap in self.caps:
                if corner_of is corner:
                    k[name] = np.ascontiguousarray(cap)
        types = {"flat": "uint8_t", "first": "uint8_t", "cap_a": "double", "cap_b": "double"}
        self._p = {n: pointer(ffi, a, types.get(n, "int64_t")) for n, a in k.items()}
        self._p["y"] = pointer(ffi, self.y, "double")
        self._p["qe"] = pointer(ffi, self.qe, "double")

    def rate_candidates(self, E: Int, row: Int, cand: Float) -> Float:
        """The worst quality over each vertex's entries among ``E`` (whole segments) of
        each candidate of the vertex, ``cand[row[vertex]]`` ``(rows, nc, 2)``:
        ``(segments, nc)``."""
        if self.kernels is None:
            starts = np.flatnonzero(self.first[E])
            q = self.rate(E, cand[row[self.ev[E]]])
            return np.minimum.reduceat(q, starts, axis=0) if len(starts) else q[:0]
        ffi, lib, p = self.kernels.ffi, self.kernels.lib, self._p
        nc = cand.shape[1]
        E = np.ascontiguousarray(E, dtype=np.int64)
        row = np.ascontiguousarray(row, dtype=np.int64)
        out = np.empty((int(np.count_nonzero(self.first[E])), nc))
        lib.rate_candidates(
            p["y"], p["ea"], p["eb"], p["ev"], p["flat"], p["cap_a"], p["cap_b"],
            pointer(ffi, row, "int64_t"), pointer(ffi, cand, "double"), nc,
            pointer(ffi, E, "int64_t"), len(E), p["first"], _ANGLE_SCALE,
            _RADIUS_SCALE4, pointer(ffi, out, "double"),
        )  # fmt: skip
        return out

    def rate(self, E: Int, p: Float) -> Float:
        """Qualities of the entries ``E`` with their vertex at ``p (len(E), ..., 2)``."""
        y = self.y
        col = (slice(None),) + (None,) * (p.ndim - 2)
        px, py = p[..., 0], p[..., 1]
        a, b = y[self.ea[E]], y[self.eb[E]]
        lab = np.hypot(b[:, 0] - a[:, 0], b[:, 1] - a[:, 1])
        q = _star_quality(
            px, py, a[col + (0,)], a[col + (1,)], b[col + (0,)], b[col + (1,)], lab[col]
        )
        if self.any_flat:
            q[self.flat[E]] = -1.0
        i = np.flatnonzero(self.capped[E]) if self.caps else ()
        if len(i):
            Ei, pi = E[i], p[i]
            for corner_of, cap in self.caps:  # cap = inf where that corner caps nothing
                d = pi - y[corner_of[Ei]][col]
                d = np.hypot(d[..., 0], d[..., 1])
                q[i] = np.where(d > cap[Ei][col], -1.0, q[i])
        return q

    def background_minima(self, x0: Float, m: int) -> Float:
        """The worst quality around each movable vertex ``(m,)`` at the background positions
        ``x0`` (inf without entries; -1 where a triangle is degenerate there)."""
        if not len(self.ev):
            return np.full(m, np.inf)
        if self.kernels is not None:
            star = np.full(m, np.inf)
            ffi, k = self.kernels.ffi, self._p
            self.kernels.lib.background_minima(
                pointer(ffi, np.ascontiguousarray(x0, dtype=np.float64), "double"), k["pv"],
                k["ea"], k["eb"], k["ev"], len(self.ev), _ANGLE_SCALE, _RADIUS_SCALE4,
                pointer(ffi, star, "double"),
            )  # fmt: skip
            return star
        p, a, b = x0[self.verts[self.ev]], x0[self.ea], x0[self.eb]
        lab = np.hypot(b[:, 0] - a[:, 0], b[:, 1] - a[:, 1])
        return self._vertex_minima(
            _star_quality(p[:, 0], p[:, 1], a[:, 0], a[:, 1], b[:, 0], b[:, 1], lab), m
        )

    def star_minima(self, changed: Bool, m: int) -> Float:
        """The worst quality around each movable vertex ``(m,)`` (inf without entries),
        re-rating the entries with a corner among the ``changed`` vertices."""
        ev = self.ev
        if not len(ev):
            return np.full(m, np.inf)
        if self.kernels is None:
            touched = changed[self.pv] | changed[self.ea] | changed[self.eb]
            D = np.flatnonzero(touched)
            self.qe[D] = self.rate(D, self.y[self.pv[D]])
            return self._vertex_minima(self.qe, m)
        ffi, p = self.kernels.ffi, self._p
        star = np.full(m, np.inf)
        self.kernels.lib.star_minima(
            p["y"], p["pv"], p["ea"], p["eb"], p["ev"], p["flat"], p["cap_a"], p["cap_b"],
            len(ev), pointer(ffi, changed.view(np.uint8), "uint8_t"), _ANGLE_SCALE,
            _RADIUS_SCALE4, p["qe"], pointer(ffi, star, "double"),
        )  # fmt: skip
        return star

    def _vertex_minima(self, q: Float, m: int) -> Float:
        """The minimum of entry values ``q`` over each movable vertex's entries ``(m,)``
        (inf for vertices without entries here)."""
        star = np.full(m, np.inf)
        star[self.ev[self.vstart]] = np.minimum.reduceat(q, self.vstart)
        return star


class _Compass:
    """The compass search of :func:`relax_triangles`: candidates, steps and moves.

    Each sweep, every active vertex gets :data:`DIRECTIONS` directions (rotated by the
    golden angle from sweep to sweep) at :data:`STEPS` times its step, and the vertices on
    Gamma slide both ways along Gamma at :data:`GAMMA_STEPS` (projected, with the normals
    there); candidate 0 is the current position. A vertex's candidates depend on its own
    position only, which changes only when its colour moves, so they are generated (and
    projected) once per sweep.
    """

    def __init__(
        self,
        comm: MPI.Comm,
        sub: SubVertices,
        onto_gamma: Callable[[Float], tuple[Float, Float]],
        y: Float,
        normal: Float,
        on_gamma: Bool,
        h: Float,
        frame: RelaxFrame | None = None,
        x0: Float | None = None,
    ) -> None:
        self.comm, self.sub, self.onto_gamma, self.y = comm, sub, onto_gamma, y
        self.frame = frame
        verts = sub.vertices
        self.gamma = np.flatnonzero(on_gamma[verts])
        self.tangent = rot90(normal[verts[self.gamma]])  # Omega on their left
        # With a mirror: each vertex's side of it (from its background position), the
        # slides of the vertices on the mirror stopped, and the slides' order reversed on
        # the negative side (the first slide of a vertex and of its image are images).
        self.side: npt.NDArray[np.int64] | None = None
        if frame is not None and frame.mirror is not None and x0 is not None:
            self.side = frame.side(x0[verts])
            self.tangent *= self.side[self.gamma, None]
        self.nrm = normal.copy()  # normals at the current positions of the vertices on Gamma
        self.step = INITIAL_STEP * h[verts]
        self.hmax = MAX_STEP * h[verts]
        self.hmin = MIN_STEP * h[verts]
        gsteps = np.asarray(GAMMA_STEPS)
        self.tangential = np.concatenate([gsteps, -gsteps])[:, None]
        slide_full = np.concatenate([gsteps, gsteps]) == gsteps[0]
        self.nc = nc = 1 + DIRECTIONS * len(STEPS)
        self.full_step = np.zeros((2, nc), dtype=bool)  # at the full step: inside, on Gamma
        self.full_step[0, 1 : 1 + DIRECTIONS] = True
        self.full_step[1, 1 : 1 + len(self.tangential)] = slide_full
        self.is_gamma = np.zeros(len(verts), dtype=np.int64)
        self.is_gamma[self.gamma] = 1
        self.row = np.full(len(verts), -1, dtype=np.int64)
        self.rowof = np.zeros(len(verts), dtype=np.int64)  # scratch: each vertex's row of S
        self.cand = np.zeros((0, nc, 2))
        self.cand_n: Float | None = None
        self.kernels = relax_kernels()
        self._pointers: dict[str, Any] | None = None
        self._cand_buffer = np.empty(0)  # the candidates' memory, reused from sweep to sweep

    def generate(self, active: Bool, sweep: int) -> None:
        """The candidates of the ``active`` vertices in this ``sweep`` (collective)."""
        y, verts, dim = self.y, self.sub.vertices, self.y.shape[1]
        act = np.flatnonzero(active)
        self.row = row = np.full(len(verts), -1, dtype=np.int64)
        row[act] = np.arange(len(act))
        golden = np.pi * (3.0 - np.sqrt(5.0))
        theta = sweep * golden + 2.0 * np.pi * np.arange(DIRECTIONS) / DIRECTIONS
        dirs = np.column_stack([np.cos(theta), np.sin(theta)])

        def offsets_of(dirs: Float) -> Float:
            if self.frame is not None:
                dirs = self.frame.directions(dirs)
            steps = np.asarray(STEPS)[:, None, None] * dirs
            return np.concatenate([np.zeros((1, dim)), steps.reshape(-1, dim)])

        offsets = offsets_of(dirs)
        step = self.step
        if self.side is not None:  # mirrored directions below the mirror, in it on it
            assert self.frame is not None and self.frame.mirror is not None
            flipped, inplane = dirs.copy(), dirs.copy()
            flipped[:, self.frame.mirror] *= -1.0
            inplane[:, self.frame.mirror] = 0.0
            by_side = np.stack([offsets_of(flipped), offsets_of(inplane), offsets])
            self.cand = cand = (
                y[verts[act]][:, None, :] + step[act, None, None] * by_side[self.side[act] + 1]
            )
        elif self.kernels is None:
            self.cand = cand = y[verts[act]][:, None, :] + step[act, None, None] * offsets[None]
        else:
            size = len(act) * self.nc * dim
            if len(self._cand_buffer) < size:
                self._cand_buffer = np.empty(size)
            self.cand = cand = self._cand_buffer[:size].reshape(len(act), self.nc, dim)
            ffi, k = self.kernels.ffi, self._kernel_pointers(self.kernels.ffi)
            self.kernels.lib.compass_candidates(
                k["y"], k["verts"], pointer(ffi, act, "int64_t"), len(act), k["step"],
                pointer(ffi, np.ascontiguousarray(offsets), "double"), self.nc,
                pointer(ffi, cand, "double"),
            )  # fmt: skip
        # Vertices on Gamma: +-tangent steps, projected onto Gamma (the other candidates
        # repeat their current position).
        gamma = self.gamma
        ga = np.flatnonzero(active[gamma])
        g = gamma[ga]
        self.cand_n = None  # the normals at the candidates of the vertices on Gamma
        if self.comm.allreduce(len(g) > 0, op=MPI.LOR):  # (a projection costs ~1 ms)
            tangential = self.tangential
            slide = step[g, None, None] * tangential[None] * self.tangent[ga, None, :]
            pg = (y[verts[g]][:, None, :] + slide).reshape(-1, dim)
            pc, pn = collective_call(self.comm, "projection onto Gamma", self.onto_gamma, pg)
            shape = (len(g), len(tangential), dim)
            cand[row[g]] = y[verts[g]][:, None, :]
            cand[row[g], 1 : 1 + len(tangential)] = np.reshape(pc, shape)
            self.cand_n = cand_n = np.empty_like(cand)
            cand_n[row[g]] = self.nrm[verts[g]][:, None, :]
            cand_n[row[g], 1 : 1 + len(tangential)] = np.reshape(pn, shape)

    def move_colours(
        self, colours: Int, bounds: Int, active: Bool, stars: _Stars, changed: Bool
    ) -> int:
        """The moves of :meth:`move` for the ``colours`` one after the other, on one rank,
        in one call of the C kernel (the entries of colour ``k`` are
        ``bounds[k]:bounds[k + 1]``); ``changed`` is set at the vertices that moved.
        Returns the number of moves."""
        kernels = self.kernels
        assert kernels is not None
        ffi, p = kernels.ffi, stars._p
        k = self._kernel_pointers(ffi)
        cand_n = ffi.NULL if self.cand_n is None else pointer(ffi, self.cand_n, "double")
        moves = kernels.lib.move_colours(
            p["y"], p["ea"], p["eb"], p["ev"], p["flat"], p["cap_a"], p["cap_b"],
            pointer(ffi, np.ascontiguousarray(bounds, dtype=np.int64), "int64_t"),
            pointer(ffi, np.ascontiguousarray(colours, dtype=np.int64), "int64_t"),
            len(colours), pointer(ffi, active.view(np.uint8), "uint8_t"),
            pointer(ffi, self.row, "int64_t"), pointer(ffi, self.cand, "double"), cand_n,
            self.nc, k["verts"], k["is_gamma"], k["full_step"], k["step"], k["hmax"],
            k["nrm"], pointer(ffi, changed.view(np.uint8), "uint8_t"), TIE, _GROW, _HOLD,
            _SHRINK, _ANGLE_SCALE, _RADIUS_SCALE4,
        )  # fmt: skip
        if moves < 0:
            raise ValueError(f"move_colours: {self.nc} candidates per vertex, at most 64")
        return int(moves)

    def _kernel_pointers(self, ffi: Any) -> dict[str, Any]:
        """Pointers to the arrays of :meth:`move_colours` that stay (written in place)."""
        if self._pointers is None:
            self._verts64 = np.ascontiguousarray(self.sub.vertices, dtype=np.int64)
            self._full_step8 = self.full_step.astype(np.uint8)
            self._pointers = {
                "verts": pointer(ffi, self._verts64, "int64_t"),
                "is_gamma": pointer(ffi, self.is_gamma, "int64_t"),
                "full_step": pointer(ffi, self._full_step8, "uint8_t"),
                "step": pointer(ffi, self.step, "double"),
                "hmax": pointer(ffi, self.hmax, "double"),
                "nrm": pointer(ffi, self.nrm, "double"),
                "y": pointer(ffi, self.y, "double"),
            }
        return self._pointers

    def move(self, S: Int, E: Int, stars: _Stars) -> Int:
        """Move the active vertices ``S`` of one colour, whose entries are ``E``, each to its
        best candidate if that beats staying (collective); return those that moved."""
        sub, verts, row, cand = self.sub, self.sub.vertices, self.row, self.cand
        ev = stars.ev
        qmin = stars.rate_candidates(E, row, cand)  # E holds whole segments
        if sub.map is None:
            qs, S = qmin, ev[E[stars.first[E]]]
        else:
            self.rowof[S] = np.arange(len(S))
            qs = np.full((len(S), self.nc), np.inf)
            qs[self.rowof[ev[E[stars.first[E]]]]] = qmin
            qs = sub.reduce_rows(S, qs, "min")
        # The first candidate (fixed order) within TIE of the best, taken if it beats
        # the current position by more than TIE: decisions that rounding cannot flip.
        best = np.argmax(qs >= qs.max(axis=1, initial=-np.inf)[:, None] - TIE, axis=1)
        gain = qs[np.arange(len(S)), best] > qs[:, 0] + TIE
        win, bw = S[gain], best[gain]
        self.y[verts[win]] = cand[row[win], bw]
        on = self.is_gamma[win] == 1
        if self.cand_n is not None and on.any():
            self.nrm[verts[win[on]]] = self.cand_n[row[win[on]], bw[on]]
        # Grow the step after a full step, shrink it where nothing helped.
        factor = np.full(len(S), _SHRINK)
        factor[gain] = np.where(self.full_step[self.is_gamma[win], bw], _GROW, _HOLD)
        self.step[S] = np.minimum(factor * self.step[S], self.hmax[S])
        return win
