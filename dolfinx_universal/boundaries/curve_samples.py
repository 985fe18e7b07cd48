"""Starts of the closest-point searches of planar curves: the candidate samples of a dense
sampling of Gamma near each point, and the cubic start of the bracketed Newton method."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from dolfinx_universal.core.arrays import Bool, Float, Int, norm2

__all__ = [
    "WINDOWS",
    "SampleHints",
    "candidates",
    "hermite_root",
    "neighbours",
    "window_clearance",
]


def neighbours(lengths: Sequence[int]) -> tuple[Int, Int]:
    """Previous and next index of every point of closed loops stored one after the other."""
    n = np.asarray(lengths, dtype=np.intp)
    start, size = np.repeat(np.cumsum(n) - n, n), np.repeat(n, n)
    i = np.arange(n.sum()) - start
    return start + (i - 1) % size, start + (i + 1) % size


def candidates(
    x: Float,
    tree: cKDTree,
    pts: Float,
    prev: Int,
    nxt: Int,
    reach: float,
    clear: tuple[Float, ...],
    start: Int | None = None,
) -> tuple[Int, Int]:
    """Start samples for the exact projection of every point of ``x``.

    Returns pairs ``(point index, sample index)``: the samples that are discrete local minima
    of ``|x - sample|`` along their loop, among those within ``d_min + reach`` of ``x``
    (``d_min``: nearest sample distance). With ``reach`` at least half the longest arc between
    consecutive samples, this includes a sample next to the interval of the global closest
    point (the sample nearest to it is within ``d + reach``; if the distance is unimodal over
    neighbouring intervals, the discrete minimum is that sample or its neighbour).

    Search: the samples within ``d_min + reach`` of most points are a few neighbours along the
    loop of the nearest sample. A window of samples on each side of it (:data:`WINDOWS`:
    first a narrow one, enough near Gamma, then a wide one) is searched directly, and the
    nearest sample's clearance ``clear`` for that window (:func:`window_clearance`), or else
    a ball count of the k-d tree, proves that no other sample is that close (else the point
    goes on). The k nearest samples (k = 16, then 64) settle most other points; the rest
    (far from Gamma) are searched exhaustively. The candidates do not depend on the route.

    ``start`` (optional, -1 where unknown): a sample near each point's nearest one. The
    windows are first searched around it, with no query of the tree; the points for which
    they do not prove to hold the nearest sample go the way above.
    """
    ps: list[Int] = []
    ss: list[Int] = []
    m = len(pts)
    todo = np.arange(len(x))
    if len(x):
        left = np.ones(len(x), dtype=bool)
        if start is not None:
            started = np.flatnonzero(start >= 0)
            js = start[started]
            ds = np.sqrt((x[started, 0] - pts[js, 0]) ** 2 + (x[started, 1] - pts[js, 1]) ** 2)
            for w, cw in zip(WINDOWS, clear):
                if w != max(WINDOWS):  # the points its clearance may settle (ds >= d_min)
                    sub = started[(cw[js] - ds) * (1 - 1e-9) > (ds + reach) * (1 + 1e-9)]
                else:  # the wide window: the points the narrow one left
                    sub = started[left[started]]
                if not len(sub):
                    continue
                done, pi, si = _window_candidates(
                    x[sub], None, start[sub], tree, pts, nxt, reach, cw, w
                )
                ps.append(sub[pi])
                ss.append(si)
                left[sub[done]] = False
        d0, j0 = np.zeros(len(x)), np.zeros(len(x), dtype=np.intp)
        rest = np.flatnonzero(left)
        if len(rest):
            d0[rest], j0[rest] = tree.query(x[rest])
        for w, cw in zip(WINDOWS, clear):  # a narrow window first, then the wide one
            sub = np.flatnonzero(left)
            if w != max(WINDOWS):  # only the points its clearance settles
                d, j = d0[sub], j0[sub]
                sub = sub[(cw[j] - d) * (1 - 1e-9) > (d + reach) * (1 + 1e-9) + 1e-300]
            if not len(sub):
                continue
            done, pi, si = _window_candidates(
                x[sub], d0[sub], j0[sub], tree, pts, nxt, reach, cw, w
            )
            ps.append(sub[pi])
            ss.append(si)
            left[sub[done]] = False
        todo = np.flatnonzero(left)
    for k in (min(16, m), min(64, m)):
        if not todo.size:
            break
        d, j = tree.query(x[todo], k=k)  # distances sorted: column 0 is the nearest
        lim = d[:, :1] + reach
        done = (d[:, -1] > lim[:, 0]) | (k == m)
        r, c = np.nonzero((d <= lim) & done[:, None])
        jj, dd, xr = j[r, c], d[r, c], x[todo[r]]
        keep = (c == 0) | (dd <= norm2(xr - pts[prev[jj]])) & (dd <= norm2(xr - pts[nxt[jj]]))
        ps.append(todo[r[keep]])
        ss.append(jj[keep])
        todo = todo[~done]
    for chunk in np.array_split(todo, todo.size * m // 1_000_000 + 1) if todo.size else []:
        d = norm2(x[chunk][:, None, :] - pts[None])
        lim = d.min(axis=1, keepdims=True) + reach
        cand = (d <= lim) & (d <= d[:, prev]) & (d <= d[:, nxt])
        cand[np.arange(len(chunk)), d.argmin(axis=1)] = True
        r, c = np.nonzero(cand)
        ps.append(chunk[r])
        ss.append(c)
    if not ps:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
    return np.concatenate(ps).astype(np.intp), np.concatenate(ss).astype(np.intp)


WINDOWS = (4, 16)
"""Samples on each side of the nearest one searched directly by :func:`candidates`: the
narrow window settles the points near Gamma (within a few sample spacings), the wide one
most others."""


class SampleHints:
    """Starts for the window search of :func:`candidates` on one closed loop of samples.

    Square cells of side :data:`_HINT_CELL` sample spacings, those within
    :data:`_HINT_BAND` cells of the loop, hashed sparsely (sorted keys), each with the
    sample nearest its centre (one query of the k-d tree when built). A point's start is
    its cell's sample, moved along the loop by the point's offset along the chord there
    (:data:`_HINT_WALK` times): near its nearest sample, which the windows then prove.

    Parameters
    ----------
    pts
        The loop's samples in order ``(n, 2)``.
    tree
        A k-d tree of ``pts``.
    prev, nxt
        Each sample's neighbours along the loop ``(n,)``.
    spacing
        The longest chord between consecutive samples.
    """

    def __init__(self, pts: Float, tree: cKDTree, prev: Int, nxt: Int, spacing: float) -> None:
        self.c = c = _HINT_CELL * max(spacing, 1e-300)
        ij = np.floor(pts[:: max(1, _HINT_CELL // 2)] / c).astype(np.int64)  # two per cell
        r = np.arange(-_HINT_BAND, _HINT_BAND + 1)
        off = np.stack(np.meshgrid(r, r, indexing="ij"), -1).reshape(-1, 2)
        self.keys = np.unique(self._key(ij[:, None, :] + off[None]))
        i, j = np.divmod(self.keys, _KEY_BASE)
        centres = (np.column_stack([i, j]) - _KEY_OFFSET + 0.5) * c
        self.near = np.asarray(tree.query(centres)[1], dtype=np.intp)
        # Per sample: its coordinates, the chord of its neighbours and 2 / its length^2.
        self.px, self.py = np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1])
        self.tx, self.ty = self.px[nxt] - self.px[prev], self.py[nxt] - self.py[prev]
        with np.errstate(divide="ignore"):
            self.scale = np.where(
                (self.tx != 0) | (self.ty != 0), 2.0 / (self.tx**2 + self.ty**2), 0.0
            )

    @staticmethod
    def _key(ij: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
        ij = np.clip(ij, -_KEY_OFFSET, _KEY_OFFSET - 1) + _KEY_OFFSET
        return ij[..., 0] * _KEY_BASE + ij[..., 1]

    def starts(self, x: Float) -> Int:
        """A start sample for each point of ``x (m, 2)``, -1 outside the cells."""
        ok = np.isfinite(x).all(axis=1)
        u = np.where(ok[:, None], x / self.c, 0.0)
        key = self._key(np.floor(np.clip(u, -(2.0**62), 2.0**62)).astype(np.int64))
        pos = np.minimum(np.searchsorted(self.keys, key), len(self.keys) - 1)
        hit = ok & (self.keys[pos] == key)
        start = np.full(len(x), -1, dtype=np.intp)
        k = np.flatnonzero(hit)
        j, x0, x1, n = self.near[pos[k]], x[k, 0], x[k, 1], len(self.px)
        for _ in range(_HINT_WALK):  # the offset along the chord, in samples
            off = ((x0 - self.px[j]) * self.tx[j] + (x1 - self.py[j]) * self.ty[j]) * self.scale[j]
            j = (j + np.clip(np.rint(off), -_HINT_CELL, _HINT_CELL).astype(np.intp)) % n
        start[k] = j
        return start


_HINT_CELL = 8
"""Side of the cells of :class:`SampleHints`, in sample spacings."""

_HINT_BAND = 6
"""Cells of :class:`SampleHints` around each cell of the loop: points up to about 48
sample spacings from Gamma get a start (the band of a mesh reaches a few ``h``)."""

_HINT_WALK = 2
"""Steps along the chord from a cell's sample: the start is then within a sample or two of
the nearest one (measured on the propeller and three-blade bodies)."""

_KEY_OFFSET = 2**30

_KEY_BASE = 2**31


def window_clearance(tree: cKDTree, pts: Float, nxt: Int) -> tuple[Float, ...]:
    """For each window of :data:`WINDOWS` and each sample, a lower bound of the sample's
    distance to the samples outside its window (the ``w`` samples on each side along its
    loop, and itself), ``(n,)`` each.

    From its ``2 w + 5`` nearest samples (``w`` the widest window): the distance to the
    nearest of them outside the window, else to the farthest of them (every other sample
    is at least that far).
    """
    n = len(pts)
    k = min(2 * max(WINDOWS) + 5, n)
    d, j = tree.query(pts, k=k)
    d, j = d.reshape(n, k), j.reshape(n, k)
    ends = np.flatnonzero(nxt != np.arange(1, n + 1))  # last sample of each loop
    loop = np.searchsorted(ends, np.arange(n))
    size = (ends - np.concatenate([[-1], ends[:-1]]))[loop]
    step = (j - np.arange(n)[:, None]) % size[:, None]
    other = loop[j] != loop[:, None]
    out = []
    for w in WINDOWS:
        outside = other | ((step > w) & (step < size[:, None] - w))
        first = np.argmax(outside, axis=1)
        out.append(np.where(outside.any(axis=1), d[np.arange(n), first], d[:, -1]))
    return tuple(out)


def _window_candidates(
    x: Float,
    d0: Float | None,
    j0: Int,
    tree: cKDTree,
    pts: Float,
    nxt: Int,
    reach: float,
    clear: Float,
    w: int,
) -> tuple[Bool, Int, Int]:
    """The candidates of :func:`candidates` for the points whose samples within reach all
    lie within ``w`` samples of the nearest one ``j0`` (at ``d0``) along its loop.

    With ``d0`` None, ``j0`` is only a start near the nearest sample: the window around it is
    searched for the nearest one, and a point is settled when the clearance proves that no
    sample outside the window is within reach of that nearest one (then it is in the window,
    and the candidates are those of the nearest sample's window).

    Returns the mask of the points settled, and their pairs ``(point, sample)``.
    """
    n = len(pts)
    off = np.arange(-w - 1, w + 2)
    ends = np.flatnonzero(nxt != np.arange(1, n + 1))  # last sample of each loop
    if len(ends) == 1:  # one loop: samples 0 .. n - 1
        size = np.full(len(j0), n)
        win = j0[:, None] + off
        if n > 2 * w + 3:  # a window wraps around at most once
            win[win < 0] += n
            win[win >= n] -= n
        else:
            win %= n
    else:
        loop = np.searchsorted(ends, j0)
        start = nxt[ends][loop]
        size = ends[loop] - start + 1
        win = start[:, None] + ((j0 - start)[:, None] + off) % size[:, None]
    # (points, 2 w + 3): the window and one more each side; by coordinate columns (the
    # arithmetic of norm2, in fewer passes over strided data)
    dx, dy = x[:, :1] - pts[:, 0][win], x[:, 1:2] - pts[:, 1][win]
    d = np.sqrt(dx**2 + dy**2)
    inner = d[:, 1:-1]
    nearest = np.full(len(x), w)  # the nearest sample's column in the window
    if d0 is None:  # from a start: the window's nearest, and the start's distance
        nearest = inner.argmin(axis=1)
        d0, dj = inner[np.arange(len(x)), nearest], inner[:, w]
    else:
        dj = d0
    lim = d0 + reach
    # Every sample within `wide` (slightly enlarged against rounding) must be inner. The
    # samples outside the window lie at least clear[j0] - dj from x (triangle inequality,
    # dj the distance to the window's centre j0);
    # where that does not prove it, a ball count of the tree decides.
    wide = lim * (1 + 1e-9) + 1e-300
    done = (clear[j0] - dj) * (1 - 1e-9) > wide
    rest = np.flatnonzero(~done & (size > 2 * w + 3))
    if len(rest) and w == max(WINDOWS):  # the narrow window leaves the rest to the wide one
        count = tree.query_ball_point(x[rest], wide[rest], return_length=True)
        done[rest] = count == (inner[rest] <= wide[rest, None]).sum(axis=1)
    done &= size > 2 * w + 3
    close = (inner <= lim[:, None]) & (inner <= d[:, :-2]) & (inner <= d[:, 2:])
    close[np.arange(len(x)), nearest] = True  # the nearest sample
    r, c = np.nonzero(close & done[:, None])
    return done, r, win[r, c + 1]


def hermite_root(
    g0: Float, g1: Float, dg0: Float, dg1: Float, lo: Float, hi: Float
) -> tuple[Float, Float]:
    """A start for :func:`~dolfinx_universal.boundaries.numerics.bracketed_newton`: the root
    in ``[lo, hi]`` of the cubic that interpolates ``g`` and ``g'`` at both ends
    (``g0 <= 0 <= g1``), by a few Newton steps on the cubic from the secant's root, kept in
    the bracket; and :data:`_CURVATURE_SAFETY` times the cubic's largest ``|g''|`` over the
    bracket.

    Its error is ``O((hi - lo)^4)``, far below the secant's ``O((hi - lo)^2)``: one Newton
    step on ``g`` then reaches rounding, which the bound of ``|g''|`` tells without another
    evaluation (one evaluation of the curve instead of three).
    """
    h = hi - lo
    m0, m1 = dg0 * h, dg1 * h
    # g(lo + s h) = g0 + m0 s + a s^2 + b s^3 on [0, 1]
    a = 3.0 * (g1 - g0) - 2.0 * m0 - m1
    b = 2.0 * (g0 - g1) + m0 + m1
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        s = np.clip(-g0 / (g1 - g0), 0.0, 1.0)
        for _ in range(_HERMITE_STEPS):
            f = g0 + s * (m0 + s * (a + s * b))
            df = m0 + s * (2.0 * a + 3.0 * s * b)
            s = np.clip(s - f / df, 0.0, 1.0)
        # g'' = (2 a + 6 b s) / h^2 is linear in s: its extremes are at the ends.
        curvature = _CURVATURE_SAFETY * np.maximum(np.abs(2.0 * a), np.abs(2.0 * a + 6.0 * b))
        curvature /= h * h
    return lo + s * h, curvature


_HERMITE_STEPS = 2
"""Newton steps on the cubic of :func:`hermite_root` (from the secant's root, whose error
is ``O(h^2)``: after two steps the start is within ``O(h^4)`` of the root of ``g``, which
one Newton step on ``g`` then takes to rounding)."""

_CURVATURE_SAFETY = 4.0
"""Factor on the cubic's ``|g''|`` in the bound
:func:`~dolfinx_universal.boundaries.numerics.bracketed_newton` stops on: the cubic's ``g''``
differs from that of ``g`` by ``O(h^2)`` relative (``h`` the bracket, one sample spacing on
each side)."""
