"""Immersed boundaries Gamma of planar domains: signs, closest points, distances and normals."""

from __future__ import annotations

import abc
import json
import warnings
from collections.abc import Callable, Sequence
from functools import cached_property
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.interpolate import CubicSpline
from scipy.spatial import cKDTree

from dolfinx_universal.core.arrays import (
    Bool,
    Float,
    Int,
    as_points,
    cross2,
    norm2,
    positive,
    rot90,
)

__all__ = [
    "Boundary",
    "Circle",
    "Domain",
    "Ellipse",
    "ImplicitCurve",
    "ParametricCurve",
    "PeriodicSpline",
    "PolarCurve",
    "RigidMotion",
]

ArrayFn = Callable[[Float], Float]

_EPS = float(np.finfo(np.float64).eps)
_GRID_CELLS = 1024  # cells of the sign/distance acceleration grid along the bbox's longer side


# ----------------------------------------------------------------------------- helpers
def _vector(v: npt.ArrayLike, name: str, dim: int = 2) -> Float:
    """A finite ``dim``-vector (the first ``dim`` numbers of ``v``)."""
    a = np.asarray(v, dtype=np.float64).reshape(-1)[:dim]
    if a.shape != (dim,) or not np.isfinite(a).all():
        words = {2: "two", 3: "three"}.get(dim, str(dim))
        raise ValueError(f"{name} must be {words} finite numbers, got {v!r}")
    return a


def _distance(distance: float) -> float:
    d = float(distance)
    if not (np.isfinite(d) and d >= 0):
        raise ValueError(f"distance must be a finite number >= 0, got {distance}")
    return d


def _distances(distance: float | npt.ArrayLike, n: int) -> Float:
    """``distance`` (one, or one per point) as ``n`` finite numbers ``>= 0``."""
    if np.ndim(distance) == 0:
        return np.full(n, _distance(float(distance)))  # type: ignore[arg-type]
    d = np.asarray(distance, dtype=np.float64)
    if d.shape != (n,):
        raise ValueError(f"distance must be a number or one per point ({n},), got {d.shape}")
    if not (np.isfinite(d) & (d >= 0)).all():
        raise ValueError("distance must be finite numbers >= 0")
    return d


ONTO_REACH = 2.5
"""The level-set boundaries' :meth:`Boundary.onto_gamma` accepts a point of Gamma on a point's
gradient line only within this many times Newton's estimate of the offset
(``|f| / |grad f|``): at a point near Gamma the zero lies within a few percent of the
estimate; one farther out is left to the closest point."""


def _onto_or_closest(
    b: Boundary, x: Float, y: Float, ok: Bool, f: Float, g: Float, scale: float
) -> tuple[Float, Float]:
    """The level-set boundaries' :meth:`Boundary.onto_gamma` from points ``y`` moved onto
    Gamma along gradient lines (``ok`` where that succeeded) with the level-set function
    ``f`` and its gradient ``g`` there: the points on Gamma to the closest points' tolerance
    (``|f| <= 1e-12 scale |g|``) with the unit normals ``g / |g|``, the closest points and
    normals of ``x`` elsewhere. ``y`` is overwritten."""
    gn = _normd(g)
    ok = ok & (gn > 0) & (np.abs(f) <= 1e-12 * scale * gn)
    n = np.zeros_like(y)
    n[ok] = g[ok] / gn[ok, None]
    bad = np.flatnonzero(~ok)
    if bad.size:
        y[bad], n[bad] = b.closest_normal(x[bad])
    return y, n


def _native(obj: object, cls: type, *names: str) -> bool:
    """Whether ``obj``'s class keeps ``cls``'s methods ``names`` (no subclass overrides them):
    shortcuts that bypass them are then exact."""
    return all(getattr(type(obj), n) is getattr(cls, n) for n in names)


def _call(fn: ArrayFn, arg: Float, shape: tuple[int, ...], name: str = "") -> Float:
    """``fn(arg)`` as a float64 array of the given shape (scalars are broadcast); a
    ``ValueError`` naming ``name`` (or the function) if its result has another shape."""
    value = np.asarray(fn(arg), dtype=np.float64)
    try:
        return np.broadcast_to(value, shape).copy()
    except ValueError:
        who = name or getattr(fn, "__name__", "a user function")
        raise ValueError(
            f"{who} returned an array of shape {value.shape} for points of shape "
            f"{np.shape(arg)}: expected shape {shape} (or a scalar)"
        ) from None


def _normd(v: Float) -> Float:
    """Euclidean norms of the rows of ``v (..., 2)`` (as :func:`_norm`) or ``(..., 3)``."""
    if v.shape[-1] == 2:
        return norm2(v)
    return np.sqrt(v[..., 0] ** 2 + v[..., 1] ** 2 + v[..., 2] ** 2)


def _tangent_basis(normal: Float) -> Float:
    """Orthonormal tangent bases ``(n, 2, 3)`` of the planes of unit normals ``(n, 3)``.

    ``t1 = unit(e_k x N)`` with ``e_k`` the coordinate axis least aligned with ``N``, and
    ``t2 = N x t1``, so that ``(t1, t2, N)`` is right-handed (``t1 x t2 = N``). The choice
    jumps where the least aligned axis changes (no continuous choice exists on a sphere).
    """
    k = np.argmin(np.abs(normal), axis=1)
    e = np.zeros_like(normal)
    e[np.arange(len(normal)), k] = 1.0
    t1 = np.cross(e, normal)
    t1 /= _normd(t1)[:, None]
    t2 = np.cross(normal, t1)
    return np.stack([t1, t2], axis=1)


def _rotation_matrix(rotation: object, name: str = "rotation") -> Float:
    """A 3x3 rotation matrix from a matrix, a rotation vector or an ``(axis, angle)`` pair.

    Parameters
    ----------
    rotation
        A proper orthogonal matrix ``(3, 3)`` (checked to ``1e-10``, then orthonormalised),
        a rotation vector ``(3,)`` (axis times the angle in radians, right-hand rule), or a
        pair ``(axis (3,), angle)`` with any non-zero axis.
    """
    if (
        isinstance(rotation, tuple | list)
        and len(rotation) == 2
        and np.ndim(rotation[1]) == 0
        and np.size(rotation[0]) == 3
    ):
        axis = _vector(rotation[0], f"{name} axis", 3)
        length = float(np.sqrt(axis @ axis))
        angle = float(rotation[1])
        if not (length > 0 and np.isfinite(angle)):
            raise ValueError(f"{name}: the axis must be non-zero and the angle finite")
        vec = axis * (angle / length)
    else:
        a = np.asarray(rotation, dtype=np.float64)
        if a.shape == (3, 3):
            if not np.isfinite(a).all() or np.abs(a.T @ a - np.eye(3)).max() > 1e-10:
                raise ValueError(f"{name} must be an orthogonal 3x3 matrix, got {a.tolist()}")
            if np.linalg.det(a) < 0:
                raise ValueError(f"{name} must be a rotation (determinant +1), not a reflection")
            u, _, vt = np.linalg.svd(a)
            return np.asarray(u @ vt, dtype=np.float64)
        if a.shape != (3,) or not np.isfinite(a).all():
            raise ValueError(
                f"{name} must be a 3x3 rotation matrix, a rotation vector (3,) or a pair "
                f"(axis, angle), got {rotation!r}"
            )
        vec = a
    theta = float(np.sqrt(vec @ vec))
    if theta == 0:
        return np.eye(3)
    k = vec / theta
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * (K @ K)


def _rotate(v: Float, c: float, s: float) -> Float:
    """Rows of ``v (n, 2)`` rotated by the angle of cosine ``c`` and sine ``s``."""
    return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]])


def _unit(v: Float) -> Float:
    return v / norm2(v)[:, None]


def _chords(p: Float) -> Float:
    """Edge lengths of the closed polyline ``p (m, 2)``, shape ``(m,)``."""
    return norm2(np.roll(p, -1, axis=0) - p)


def _signed_area(p: Float) -> float:
    q = np.roll(p, -1, axis=0)
    return 0.5 * float((p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]).sum())


def _neighbours(lengths: Sequence[int]) -> tuple[Int, Int]:
    """Previous and next index of every point of closed loops stored one after the other."""
    n = np.asarray(lengths, dtype=np.intp)
    start, size = np.repeat(np.cumsum(n) - n, n), np.repeat(n, n)
    i = np.arange(n.sum()) - start
    return start + (i - 1) % size, start + (i + 1) % size


def _resample(loop: Float, n: int) -> Float:
    """``n`` points equally spaced in arc length along the closed polyline ``loop``."""
    closed = np.vstack([loop, loop[:1]])
    s = np.concatenate([[0.0], np.cumsum(_chords(loop))])
    u = np.arange(n) * (s[-1] / n)
    return np.column_stack([np.interp(u, s, closed[:, 0]), np.interp(u, s, closed[:, 1])])


def _split(n: int, weights: Sequence[float]) -> list[int]:
    """``n`` split proportionally to ``weights`` (largest remainders)."""
    w = np.asarray(weights, dtype=np.float64)
    q = n * w / w.sum()
    k = np.floor(q).astype(int)
    k[np.argsort(k - q)[: n - k.sum()]] += 1
    return k.tolist()


def _crossing_sign(p: Float, loops: Sequence[Float]) -> Float:
    """Even-odd ray-casting test: -1 for points of ``p (m, 2)`` enclosed by the polylines."""
    a = np.concatenate(loops)
    b = np.concatenate([np.roll(q, -1, axis=0) for q in loops])
    out = np.empty(len(p))
    for c in range(0, len(p), 64):
        px, py = p[c : c + 64, :1], p[c : c + 64, 1:]
        cut = (a[:, 1] > py) != (b[:, 1] > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = a[:, 0] + (py - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        out[c : c + 64] = np.where((cut & (px < xc)).sum(axis=1) % 2 == 1, -1.0, 1.0)
    return out


def _candidates(
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
    loop of the nearest sample. A window of samples on each side of it (:data:`_WINDOWS`:
    first a narrow one, enough near Gamma, then a wide one) is searched directly, and the
    nearest sample's clearance ``clear`` for that window (:func:`_window_clearance`), or else
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
            for w, cw in zip(_WINDOWS, clear):
                if w != max(_WINDOWS):  # the points its clearance may settle (ds >= d_min)
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
        for w, cw in zip(_WINDOWS, clear):  # a narrow window first, then the wide one
            sub = np.flatnonzero(left)
            if w != max(_WINDOWS):  # only the points its clearance settles
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


_WINDOWS = (4, 16)
"""Samples on each side of the nearest one searched directly by :func:`_candidates`: the
narrow window settles the points near Gamma (within a few sample spacings), the wide one
most others."""


class _SampleHints:
    """Starts for the window search of :func:`_candidates` on one closed loop of samples.

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
"""Side of the cells of :class:`_SampleHints`, in sample spacings."""
_HINT_BAND = 6
"""Cells of :class:`_SampleHints` around each cell of the loop: points up to about 48
sample spacings from Gamma get a start (the band of a mesh reaches a few ``h``)."""
_HINT_WALK = 2
"""Steps along the chord from a cell's sample: the start is then within a sample or two of
the nearest one (measured on the propeller and three-blade bodies)."""
_KEY_OFFSET = 2**30
_KEY_BASE = 2**31


def _window_clearance(tree: cKDTree, pts: Float, nxt: Int) -> tuple[Float, ...]:
    """For each window of :data:`_WINDOWS` and each sample, a lower bound of the sample's
    distance to the samples outside its window (the ``w`` samples on each side along its
    loop, and itself), ``(n,)`` each.

    From its ``2 w + 5`` nearest samples (``w`` the widest window): the distance to the
    nearest of them outside the window, else to the farthest of them (every other sample
    is at least that far).
    """
    n = len(pts)
    k = min(2 * max(_WINDOWS) + 5, n)
    d, j = tree.query(pts, k=k)
    d, j = d.reshape(n, k), j.reshape(n, k)
    ends = np.flatnonzero(nxt != np.arange(1, n + 1))  # last sample of each loop
    loop = np.searchsorted(ends, np.arange(n))
    size = (ends - np.concatenate([[-1], ends[:-1]]))[loop]
    step = (j - np.arange(n)[:, None]) % size[:, None]
    other = loop[j] != loop[:, None]
    out = []
    for w in _WINDOWS:
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
    """The candidates of :func:`_candidates` for the points whose samples within reach all
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
    if len(rest) and w == max(_WINDOWS):  # the narrow window leaves the rest to the wide one
        count = tree.query_ball_point(x[rest], wide[rest], return_length=True)
        done[rest] = count == (inner[rest] <= wide[rest, None]).sum(axis=1)
    done &= size > 2 * w + 3
    close = (inner <= lim[:, None]) & (inner <= d[:, :-2]) & (inner <= d[:, 2:])
    close[np.arange(len(x)), nearest] = True  # the nearest sample
    r, c = np.nonzero(close & done[:, None])
    return done, r, win[r, c + 1]


def _best(pidx: Int, dist: Float) -> Int:
    """Index of the pair with the smallest ``dist`` for each point ``0, 1, ...`` of ``pidx``."""
    if len(pidx) == pidx.max(initial=-1) + 1:  # one pair per point
        return np.argsort(pidx, kind="stable")
    order = np.lexsort((dist, pidx))
    p = pidx[order]
    first = np.ones(len(p), dtype=bool)
    first[1:] = p[1:] != p[:-1]
    return order[first]


def _hermite_root(
    g0: Float, g1: Float, dg0: Float, dg1: Float, lo: Float, hi: Float
) -> tuple[Float, Float]:
    """A start for :func:`_bracketed_newton`: the root in ``[lo, hi]`` of the cubic that
    interpolates ``g`` and ``g'`` at both ends (``g0 <= 0 <= g1``), by a few Newton steps on
    the cubic from the secant's root, kept in the bracket; and :data:`_CURVATURE_SAFETY`
    times the cubic's largest ``|g''|`` over the bracket.

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
"""Newton steps on the cubic of :func:`_hermite_root` (from the secant's root, whose error
is ``O(h^2)``: after two steps the start is within ``O(h^4)`` of the root of ``g``, which
one Newton step on ``g`` then takes to rounding)."""
_CURVATURE_SAFETY = 4.0
"""Factor on the cubic's ``|g''|`` in the bound :func:`_bracketed_newton` stops on: the
cubic's ``g''`` differs from that of ``g`` by ``O(h^2)`` relative (``h`` the bracket, one
sample spacing on each side)."""


def _bracketed_newton(
    fn: Callable[[Float, Int], tuple[Float, Float]],
    t: Float,
    lo: Float,
    hi: Float,
    tol: float,
    maxiter: int = 100,
    curvature: Float | None = None,
) -> Float:
    """Vectorised safeguarded Newton method for roots of ``g`` with ``g(lo) <= 0 <= g(hi)``.

    ``fn(t, idx)`` returns ``g`` and ``g'`` at ``t`` for the problems ``idx``. A step that
    leaves the bracket or does not halve the previous one is replaced by a bisection
    (``rtsafe``), so every problem converges; converged problems drop out: after a step
    below ``tol``, or, given a bound ``curvature`` of ``|g''|`` over the bracket, after a
    Newton step ``d`` whose successor, at most ``curvature d^2 / (2 g')`` (quadratic
    convergence), is below ``tol / 4``: that step is not taken (saving the evaluation that
    would only confirm convergence).
    """
    t, lo, hi = t.copy(), lo.copy(), hi.copy()
    dxold = hi - lo
    act = np.arange(len(t))
    for _ in range(maxiter):
        if not act.size:
            break
        ta = t[act]
        g, dg = fn(ta, act)
        neg = g < 0
        la, ha = np.where(neg, ta, lo[act]), np.where(neg, hi[act], ta)
        lo[act], hi[act] = la, ha
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            tn = ta - g / dg
            ok = (dg > 0) & (tn >= la) & (tn <= ha) & (np.abs(2 * g) <= np.abs(dxold[act] * dg))
        tn = np.where(g == 0, ta, np.where(ok, tn, 0.5 * (la + ha)))
        step = np.abs(tn - ta)
        dxold[act] = step
        t[act] = tn
        going = (step > tol) & (ha - la > tol)
        if curvature is not None:
            with np.errstate(invalid="ignore", over="ignore"):
                going &= ~(ok & (0.5 * curvature[act] * step * step <= 0.25 * tol * dg))
        act = act[going]
    return t


class _Grid:
    """Uniform grid over a boundary's bounding box, to classify points in O(1).

    Cells within one cell of a dense sample of Gamma are *marked* (code 0); every other cell
    lies in a connected region free of Gamma, whose sign (code -1 or +1) is that of one
    representative centre by ray casting against the dense polyline (exact: the centre is
    more than a cell away from Gamma, the polyline within a tiny fraction of a cell).
    ``lb`` is a lower bound of the distance from the cell to Gamma; the distance of a point
    of the cell is at most ``lb + 3 sqrt(2) h`` (``h`` the cell size: the nearest marked cell
    is within ``lb + sqrt(2) h`` of the point, and a sample within ``2 sqrt(2) h`` of every
    point of a marked cell).
    """

    def __init__(self, loops_at: Callable[[float], list[Float]], bbox: Float) -> None:
        lo, hi = bbox
        self.h = h = float(max((hi - lo).max(), 1e-300)) / _GRID_CELLS
        loops = loops_at(h / 3)  # every point of Gamma is within h/6 of a sample
        pts = np.concatenate(loops)
        self.box = bbox
        self.origin = lo - 3 * h
        self.shape = np.ceil((hi - lo) / h).astype(np.intp) + 7
        ij = np.floor((pts - self.origin) / h).astype(np.intp)
        marked = np.zeros(tuple(self.shape), dtype=bool)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                marked[ij[:, 0] + di, ij[:, 1] + dj] = True
        free = ~marked
        label, nlabel = ndimage.label(free)
        first = np.searchsorted(np.maximum.accumulate(label.ravel()), np.arange(1, nlabel + 1))
        centres = self.origin + (np.column_stack(np.unravel_index(first, label.shape)) + 0.5) * h
        rep = np.concatenate([[0.0], _crossing_sign(centres, loops)]).astype(np.int8)
        self.code = rep[label]
        lb = (ndimage.distance_transform_edt(free) - np.sqrt(2.0)) * h
        self.lb = (np.maximum(lb, 0.0) * (1 - 1e-6)).astype(np.float32)
        self.tree = cKDTree(pts)
        self.spacing = max(float(_chords(q).max()) for q in loops)

    def _cells(self, x: Float) -> tuple[Bool, Int]:
        """Mask of the points in the grid, and their flat cell indices (0 outside)."""
        u = (x - self.origin) * (1.0 / self.h)
        u0, u1 = u[:, 0], u[:, 1]  # by columns: an all() along a short axis is slow
        inside = (u0 >= 0) & (u1 >= 0) & (u0 < self.shape[0]) & (u1 < self.shape[1])
        with np.errstate(invalid="ignore"):
            k = u[:, 0].astype(np.intp) * self.shape[1] + u[:, 1].astype(np.intp)
        return inside, np.where(inside, k, 0)

    def sign_code(self, x: Float) -> Float:
        """-1 or +1 where the sign is known, 0 where it must be computed exactly."""
        inside, k = self._cells(x)
        return np.where(inside, self.code.ravel()[k], 1).astype(np.float64)

    def lower_bound(self, x: Float, cells: tuple[Bool, Int] | None = None) -> Float:
        """Lower bound of the distance to Gamma, shape ``(n,)`` (``cells``: :meth:`_cells` of
        ``x``, if known)."""
        inside, k = self._cells(x) if cells is None else cells
        out = self.lb.ravel()[k].astype(np.float64)
        xo = x[~inside]
        out[~inside] = norm2(np.maximum(np.maximum(self.box[0] - xo, xo - self.box[1]), 0.0))
        return out


# ----------------------------------------------------------------------------- interface
class Boundary(abc.ABC):
    """The boundary Gamma (one or several closed C2 curves) of an open planar domain Omega.

    Point arguments are arrays ``(n, 2)`` or ``(n, 3)`` (only the first two columns are used,
    ``n`` may be 0); results are float64 arrays ``(n,)`` or ``(n, 2)``. Non-finite points
    raise :class:`ValueError`. Points on Gamma are outside Omega (sign +1).

    :attr:`gdim` is the dimension of the space of Omega: 2 here, 3 for the surfaces of
    :mod:`dolfinx_universal.boundaries.surfaces` (whose points are ``(n, 3)``; see
    :class:`~dolfinx_universal.boundaries.surfaces.Surface`).
    """

    gdim: int = 2
    """Dimension of the space (2: curves bound planar domains, 3: surfaces bound solids)."""

    @abc.abstractmethod
    def sign(self, x: npt.ArrayLike) -> Float:
        """Exact classification of points.

        Parameters
        ----------
        x
            Points ``(n, 2)``.

        Returns
        -------
        ``(n,)``: -1.0 in Omega, +1.0 outside or on Gamma.
        """

    @abc.abstractmethod
    def closest_point(self, x: npt.ArrayLike) -> Float:
        """Closest points ``pi(x)`` of Gamma, ``(n, 2)``, for points ``x (n, 2)``."""

    @abc.abstractmethod
    def normal(self, y: npt.ArrayLike) -> Float:
        """Unit outward normals of Omega at ``pi(y)``, ``(n, 2)``, for points ``y (n, 2)``."""

    @abc.abstractmethod
    def bounding_box(self) -> Float:
        """Box ``[[xmin, ymin], [xmax, ymax]]`` containing Gamma (possibly slightly larger)."""

    @abc.abstractmethod
    def sample(self, n: int) -> Float:
        """``n`` roughly equally spaced points of Gamma, ``(n, 2)``."""

    @abc.abstractmethod
    def min_radius_of_curvature(self) -> float:
        """Smallest radius of curvature of Gamma (``inf`` where straight)."""

    def project(self, x: npt.ArrayLike) -> tuple[Float, Float]:
        """Signed distances and closest points from a single projection.

        Parameters
        ----------
        x
            Points ``(n, 2)``.

        Returns
        -------
        phi
            ``(n,)``: ``sign(x) |x - pi(x)|``, negative in Omega.
        y
            ``(n, 2)``: the closest points ``pi(x)``.
        """
        x = as_points(x, dim=self.gdim)
        y = self.closest_point(x)
        return self.sign(x) * _normd(x - y), y

    def signed_distance(self, x: npt.ArrayLike) -> Float:
        """Signed distance ``phi (n,)`` to Gamma of points ``x (n, 2)``, negative in Omega."""
        return self.project(x)[0]

    def tangent(self, y: npt.ArrayLike) -> Float:
        """Unit tangents ``(-n_y, n_x)`` at ``pi(y)``, ``(n, 2)``: Omega lies on their left."""
        return rot90(self.normal(y))

    def tangent_basis(self, y: npt.ArrayLike) -> Float:
        """Orthonormal bases of the tangent spaces of Gamma at ``pi(y)``.

        Parameters
        ----------
        y
            Points ``(n, gdim)``.

        Returns
        -------
        ``(n, gdim - 1, gdim)``: in 2D the unit tangent of :meth:`tangent` ``(n, 1, 2)``; in
        3D two unit tangents ``t1, t2`` with ``t1 x t2`` the outward normal ``(n, 2, 3)``.
        """
        if self.gdim == 2:
            return self.tangent(y)[:, None, :]
        return _tangent_basis(self.normal(y))

    def project_normal(self, x: npt.ArrayLike) -> tuple[Float, Float, Float]:
        """Signed distances, closest points and the outward normals there, from one projection.

        Parameters
        ----------
        x
            Points ``(n, 2)``.

        Returns
        -------
        phi
            ``(n,)``: as in :meth:`project`.
        y
            ``(n, 2)``: the closest points ``pi(x)``.
        normal
            ``(n, 2)``: the unit outward normals ``N(pi(x))``.
        """
        x = as_points(x, dim=self.gdim)
        phi, y = self.project(x)
        return phi, y, self.normal(y)

    def closest_normal(self, x: Float) -> tuple[Float, Float]:
        """Closest points ``(n, gdim)`` of points ``x (n, gdim)`` and the unit outward normals
        there ``(n, gdim)``, in one call: the projection the conforming step uses
        (subclasses compute both at once where that is cheaper)."""
        y = self.closest_point(x)
        return y, self.normal(y)

    def onto_gamma(self, x: Float) -> tuple[Float, Float]:
        """Points of Gamma ``(n, gdim)`` near points ``x (n, gdim)`` that lie close to it,
        and the unit outward normals there ``(n, gdim)``.

        The vertex relaxation moves its sliding candidates (steps along the tangent of Gamma
        from a vertex on Gamma, far closer to Gamma than its feature size) onto Gamma with
        it: any nearby point of Gamma will do there, not only the closest one. By default
        the closest points (:meth:`closest_normal`); a subclass may return others where
        that is much cheaper (:class:`ImplicitCurve` and
        :class:`~dolfinx_universal.boundaries.surfaces.ImplicitSurface`: along the gradient line of
        their level-set functions; :class:`PolarCurve`: along the ray from its pole).
        """
        return self.closest_normal(x)

    def _sign_closest_normal(self, x: Float) -> tuple[Float, Float, Float]:
        """:meth:`project_normal` as :meth:`Boundary.project` computes ``phi`` (the sign and
        the distance to the closest point), with the normals of :meth:`closest_normal`."""
        y, n = self.closest_normal(x)
        return self.sign(x) * _normd(x - y), y, n

    def near(self, x: npt.ArrayLike, distance: float | npt.ArrayLike) -> Bool:
        """Cheap superset of the points within ``distance`` of Gamma.

        Parameters
        ----------
        x
            Points ``(n, 2)``.
        distance
            Distance ``>= 0``: one for all points, or one per point ``(n,)``.

        Returns
        -------
        ``(n,)`` mask, true at every point with ``dist(x, Gamma) <= distance`` and possibly at
        points up to about one sample spacing farther (a grid lower bound of the distance
        discards most points; the nearest dense sample of Gamma, within ``distance + spacing``
        of every point within ``distance``, settles the others).
        """
        x = as_points(x)
        d = _distances(distance, len(x))
        on_grid = type(self)._lower_bound is Boundary._lower_bound
        if on_grid:  # the grid's bound, its cells kept for the test below
            cells = self._grid._cells(x)
            lb = self._grid.lower_bound(x, cells)
        else:
            lb = self._lower_bound(x)
        mask = lb <= d
        if mask.any():
            g = self._grid
            test = mask.copy()
            if on_grid:
                # In the grid the bound is within 3 sqrt(2) cells of the distance (see
                # _Grid): a point whose bound is that much below ``distance`` is near.
                sure = cells[0] & (lb * (1 + 1e-5) + 3 * np.sqrt(2.0) * g.h <= d)
                test &= ~sure
            if test.any():
                reach = (d[test] + g.spacing) * (1 + 1e-12)
                dist = g.tree.query(x[test], distance_upper_bound=float(reach.max()))[0]
                mask[test] = dist <= reach
        return mask

    # Private hooks of the acceleration grid, overridden where cheaper or not applicable.
    def _loops(self, spacing: float) -> list[Float]:
        """Ordered dense samples of each closed curve of Gamma, at most ``spacing`` apart."""
        n = 1024
        while True:
            p = self.sample(n)
            longest = float(_chords(p).max())
            if longest <= spacing:
                return [p]
            n = int(np.ceil(n * longest / spacing * 1.1))

    def _loops_normals(self, spacing: float) -> tuple[list[Float], list[Float]]:
        """:meth:`_loops` and the outward normals of Omega at their points (same shapes)."""
        loops = self._loops(spacing)
        normals = np.asarray(self.normal(np.concatenate(loops)), dtype=np.float64)
        return loops, np.split(normals, np.cumsum([len(q) for q in loops])[:-1])

    def _length(self) -> float:
        """Length of Gamma (approximate)."""
        return float(sum(_chords(q).sum() for q in self._loops(np.inf)))

    def _measure(self) -> float:
        """Measure of Gamma (approximate): its length in 2D, its area in 3D."""
        return self._length()

    def _lower_bound(self, x: Float) -> Float:
        """Cheap lower bound of the distance from ``x (n, 2)`` to Gamma, shape ``(n,)``."""
        return self._grid.lower_bound(x)

    @cached_property
    def _grid(self) -> _Grid:
        return _Grid(self._loops, np.asarray(self.bounding_box(), dtype=np.float64))


# ----------------------------------------------------------------------------- circle
class Circle(Boundary):
    """Omega = the open disc of the given ``center`` and ``radius``; all in closed form.

    Parameters
    ----------
    center
        Centre ``(2,)``.
    radius
        Radius ``> 0``. The centre itself projects onto ``center + (radius, 0)``.
    """

    def __init__(self, center: npt.ArrayLike, radius: float) -> None:
        self.center = _vector(center, "center")
        self.radius = positive(radius, "radius")

    def sign(self, x: npt.ArrayLike) -> Float:
        d = as_points(x) - self.center
        return np.where((d * d).sum(axis=1) < self.radius**2, -1.0, 1.0)

    def _direction(self, x: npt.ArrayLike) -> Float:
        d = as_points(x) - self.center
        r = norm2(d)
        u = np.tile([1.0, 0.0], (len(d), 1))  # the centre projects onto c + (R, 0)
        pos = r > 0
        u[pos] = d[pos] / r[pos, None]
        return u

    def closest_point(self, x: npt.ArrayLike) -> Float:
        return self.center + self.radius * self._direction(x)

    def normal(self, y: npt.ArrayLike) -> Float:
        return self._direction(y)

    def closest_normal(self, x: Float) -> tuple[Float, Float]:
        if not _native(self, Circle, "closest_point", "normal"):
            return Boundary.closest_normal(self, x)
        u = self._direction(x)
        return self.center + self.radius * u, u

    def near(self, x: npt.ArrayLike, distance: float | npt.ArrayLike) -> Bool:
        x = as_points(x)
        return self._lower_bound(x) <= _distances(distance, len(x))

    def _lower_bound(self, x: Float) -> Float:
        return np.abs(norm2(x - self.center) - self.radius)

    def bounding_box(self) -> Float:
        r = self.radius * (1 + 4 * _EPS)
        return np.array([self.center - r, self.center + r])

    def sample(self, n: int) -> Float:
        t = np.arange(n) * (2 * np.pi / max(n, 1))
        return self.center + self.radius * np.column_stack([np.cos(t), np.sin(t)])

    def min_radius_of_curvature(self) -> float:
        return self.radius

    def _length(self) -> float:
        return 2 * np.pi * self.radius


# ----------------------------------------------------------------------------- level sets
class ImplicitCurve(Boundary):
    """Gamma = {f = 0}, Omega = {f < 0} (or {f > 0} when ``inside_negative`` is False).

    ``f`` maps points ``(n, 2)`` to ``(n,)``, ``grad`` to ``(n, 2)``, ``hess`` to ``(n, 2, 2)``;
    without ``hess``, central differences of ``grad`` with step ``fd_step = 6e-6 * diag(bbox)``
    (about eps^(1/3): it only affects the convergence rate, not the converged point). ``f``
    must be a proper level-set function (``grad f != 0`` on Gamma), so that the sign of ``f``
    is the sign of the domain.

    Sampling: ``f`` is evaluated on a ``resolution``-squared grid over ``bbox`` (padded), the
    zero level set is traced by marching squares into closed loops, whose points are moved
    onto Gamma by Newton steps along ``grad f`` and resampled by arc length. Curves or
    features smaller than a grid cell may be missed: give a tight ``bbox``.

    Closest points: from the candidate samples (see :class:`ParametricCurve`), Newton's
    method on the Lagrange system ``y - x + lam grad f(y) = 0, f(y) = 0`` (``lam`` eliminated
    by its least-squares value), with steps limited to one sample spacing and a descent step
    where the Newton step would go uphill; :class:`RuntimeError` where it does not converge.

    Parameters
    ----------
    f, grad, hess
        Level-set function and its derivatives, vectorised as above.
    bbox
        ``[[xmin, ymin], [xmax, ymax]]`` containing Gamma (required).
    inside_negative
        Omega is ``{f < 0}`` if true, ``{f > 0}`` otherwise.
    resolution
        Cells of the sampling grid along each side of ``bbox``.
    n_samples
        Number of samples used to start the projections.
    """

    def __init__(
        self,
        f: ArrayFn,
        grad: ArrayFn,
        hess: ArrayFn | None = None,
        *,
        bbox: npt.ArrayLike,
        inside_negative: bool = True,
        resolution: int = 512,
        n_samples: int = 4096,
    ) -> None:
        box = np.asarray(bbox, dtype=np.float64)
        if box.shape != (2, 2) or not np.isfinite(box).all() or not (box[1] > box[0]).all():
            raise ValueError(f"bbox must be [[xmin, ymin], [xmax, ymax]], got {bbox!r}")
        self._f, self._gradf, self._hessf = f, grad, hess
        self._box = box
        self._orient = 1.0 if inside_negative else -1.0
        self.resolution, self.n_samples = int(resolution), int(n_samples)
        if self.resolution < 16 or self.n_samples < 64:
            raise ValueError("resolution must be at least 16 and n_samples at least 64")
        self._scale = float(norm2(box[1] - box[0]))
        self.fd_step = 6e-6 * self._scale

    def _s(self, y: Float) -> Float:
        return self._orient * _call(self._f, y, (len(y),), "phi")

    def _g(self, y: Float) -> Float:
        return self._orient * _call(self._gradf, y, (len(y), 2), "grad")

    def _H(self, y: Float) -> Float:
        if self._hessf is not None:
            return self._orient * _call(self._hessf, y, (len(y), 2, 2), "hess")
        e = np.eye(2) * self.fd_step
        H = np.stack([self._g(y + e[j]) - self._g(y - e[j]) for j in (0, 1)], axis=2)
        return (H + H.transpose(0, 2, 1)) / (4 * self.fd_step)

    def sign(self, x: npt.ArrayLike) -> Float:
        return np.where(self._s(as_points(x)) < 0, -1.0, 1.0)

    def _to_curve(self, y: Float, iters: int = 8) -> Float:
        """Points moved onto Gamma by Newton steps along ``grad f``."""
        y = self._newton_onto(y, iters)[0]
        if not np.isfinite(y).all():
            raise ValueError("grad f vanishes on the zero level set: f is not a proper level set")
        return y

    def _newton_onto(self, y: Float, iters: int) -> tuple[Float, Float]:
        """:meth:`_to_curve`'s steps (non-finite where ``grad f`` vanishes on the way), and
        Newton's first estimate of the offset ``|f| / |grad f|`` at the starts ``(n,)``."""
        estimate = np.full(len(y), np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            for k in range(iters):
                g, f = self._g(y), self._s(y)
                if k == 0:
                    estimate = np.abs(f) / norm2(g)
                y = y - (f / (g * g).sum(axis=1))[:, None] * g
        return y, estimate

    def onto_gamma(self, x: Float) -> tuple[Float, Float]:
        """Points of Gamma near points ``x (n, 2)`` close to it and the outward normals
        there: ``x`` moved by :meth:`_to_curve`'s Newton steps along ``grad f`` (about a
        third of the cost of a closest point). Points that end farther from ``x`` than
        :data:`ONTO_REACH` times Newton's first estimate of the offset, or not on Gamma to
        the closest points' tolerance, get their closest points."""
        if not _native(self, ImplicitCurve, "closest_point", "normal", "closest_normal"):
            return Boundary.onto_gamma(self, x)
        x = as_points(x)
        y, estimate = self._newton_onto(x, 8)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(y).all(axis=1)
            ok &= norm2(y - x) <= ONTO_REACH * estimate + 1e-12 * self._scale
        y = np.where(ok[:, None], y, x)
        return _onto_or_closest(self, x, y, ok, self._s(y), self._g(y), self._scale)

    @cached_property
    def _base_loops(self) -> list[Float]:
        """Closed loops of Gamma from marching squares (see the class docstring)."""
        n = self.resolution
        pad = (self._box[1] - self._box[0]) * (0.02 + 2.0 / n)
        lo, hi = self._box[0] - pad, self._box[1] + pad
        xs, ys = np.linspace(lo[0], hi[0], n + 1), np.linspace(lo[1], hi[1], n + 1)
        X, Y = np.meshgrid(xs, ys, indexing="ij")
        F = self._s(np.column_stack([X.ravel(), Y.ravel()])).reshape(n + 1, n + 1)
        P = F >= 0
        cx, cy = P[:-1] != P[1:], P[:, :-1] != P[:, 1:]
        ix, jx = np.nonzero(cx)
        iy, jy = np.nonzero(cy)
        wx = F[ix, jx] / (F[ix, jx] - F[ix + 1, jx])
        wy = F[iy, jy] / (F[iy, jy] - F[iy, jy + 1])
        pts = np.concatenate(
            [
                np.column_stack([xs[ix] + wx * (xs[ix + 1] - xs[ix]), ys[jx]]),
                np.column_stack([xs[iy], ys[jy] + wy * (ys[jy + 1] - ys[jy])]),
            ]
        )
        if not len(pts):
            raise ValueError("f has no zero level set in bbox")
        ex, ey = np.full(cx.shape, -1), np.full(cy.shape, -1)
        ex[cx], ey[cy] = np.arange(len(ix)), len(ix) + np.arange(len(iy))
        # crossing ids on the cell edges: bottom, right, top, left
        E = np.stack([ex[:, :-1], ey[1:, :], ex[:, 1:], ey[:-1, :]], axis=-1).reshape(-1, 4)
        cnt = (E >= 0).sum(axis=1)
        segs = [E[cnt == 2][E[cnt == 2] >= 0].reshape(-1, 2)]
        saddle = np.flatnonzero(cnt == 4)
        if saddle.size:  # resolved by the sign of the cell centre
            i, j = np.unravel_index(saddle, (n, n))
            joined = (F[i, j] + F[i + 1, j] + F[i, j + 1] + F[i + 1, j + 1] >= 0) == P[i, j]
            e = E[saddle]
            segs += [np.where(joined[:, None], e[:, [0, 1]], e[:, [3, 0]])]
            segs += [np.where(joined[:, None], e[:, [2, 3]], e[:, [1, 2]])]
        seg = np.concatenate(segs)
        if (np.bincount(seg.ravel(), minlength=len(pts)) != 2).any():
            raise ValueError("the zero level set of f is not a set of closed curves inside bbox")
        nb = seg[:, ::-1].ravel()[np.argsort(seg.ravel(), kind="stable")].reshape(-1, 2)
        seen = np.zeros(len(pts), dtype=bool)
        loops = []
        for start in range(len(pts)):  # setup only: one pass over the crossings
            if seen[start]:
                continue
            loop, prev, cur = [start], start, int(nb[start, 0])
            while cur != start:
                loop.append(cur)
                prev, cur = cur, int(nb[cur, 1] if nb[cur, 0] == prev else nb[cur, 0])
            seen[loop] = True
            loops.append(self._to_curve(pts[loop]))
        allp = np.concatenate(loops)
        tol = 1e-9 * self._scale
        if (allp < self._box[0] - tol).any() or (allp > self._box[1] + tol).any():
            raise ValueError("the zero level set of f leaves bbox: enlarge bbox")
        return loops

    def _loops(self, spacing: float) -> list[Float]:
        if not np.isfinite(spacing):
            return self._base_loops
        out = []
        for q in self._base_loops:
            n = max(8, int(np.ceil(_chords(q).sum() / spacing * 1.1)))
            while True:
                p = self._to_curve(_resample(q, n))
                longest = float(_chords(p).max())
                if longest <= spacing:
                    break
                n = int(np.ceil(n * longest / spacing * 1.1))
            out.append(p)
        return out

    @cached_property
    def _samples(self) -> tuple[Float, cKDTree, Int, Int, float]:
        loops = self._loops(self._length() / self.n_samples)
        pts = np.concatenate(loops)
        prev, nxt = _neighbours([len(q) for q in loops])
        return pts, cKDTree(pts), prev, nxt, max(float(_chords(q).max()) for q in loops)

    @cached_property
    def _clearance(self) -> tuple[Float, ...]:
        pts, tree, _, nxt, _ = self._samples
        return _window_clearance(tree, pts, nxt)

    def _newton(self, x: Float, y: Float, delta: float) -> tuple[Float, Bool]:
        """Closest points from starts ``y`` on Gamma; converged mask (see class docstring)."""
        y, ok, act = y.copy(), np.zeros(len(y), dtype=bool), np.arange(len(y))
        tol = 1e-12 * self._scale
        for _ in range(100):
            if not act.size:
                break
            ya = y[act]
            g = self._g(ya)
            gn = norm2(g)
            n = g / gn[:, None]
            tau = rot90(n)
            Ht = np.einsum("kij,kj->ki", self._H(ya), tau)
            r = ya - x[act]
            lam = -(r * n).sum(axis=1) / gn
            alpha = np.clip(-self._s(ya) / gn, -delta, delta)  # normal correction onto f = 0
            q = 1 + lam * (tau * Ht).sum(axis=1)  # reduced Hessian of |y - x|^2 / 2 on Gamma
            b = (tau * r).sum(axis=1) + alpha * lam * (n * Ht).sum(axis=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                beta = np.where(q > 0, -b / q, -np.sign(b) * delta)
            dy = alpha[:, None] * n + np.clip(beta, -delta, delta)[:, None] * tau
            y[act] = ya + dy
            step = norm2(dy)
            ok[act[step <= tol]] = True
            act = act[step > tol]  # NaN steps drop out unconverged
        return y, ok

    def closest_point(self, x: npt.ArrayLike) -> Float:
        x = as_points(x)
        if not len(x):
            return np.empty((0, 2))
        pts, tree, prev, nxt, h = self._samples
        pi, si = _candidates(x, tree, pts, prev, nxt, 0.75 * h, self._clearance)
        y, ok = self._newton(x[pi], pts[si], h)
        best = _best(pi, np.where(ok, norm2(y - x[pi]), np.inf))
        bad = np.flatnonzero(~ok[best])
        if bad.size:
            raise RuntimeError(
                f"ImplicitCurve.closest_point: Newton's method did not converge for {bad.size} "
                f"point(s), e.g. x={x[bad[0]].tolist()} (index {bad[0]})"
            )
        return y[best]

    def normal(self, y: npt.ArrayLike) -> Float:
        y = as_points(y)
        g = self._g(y)
        off = np.abs(self._s(y)) > 1e-12 * self._scale * norm2(g)
        if off.any():
            g[off] = self._g(self.closest_point(y[off]))
        return _unit(g)

    def bounding_box(self) -> Float:
        return self._box.copy()

    def sample(self, n: int) -> Float:
        loops = self._base_loops
        k = _split(n, [_chords(q).sum() for q in loops])
        out = [self._to_curve(_resample(q, m)) for q, m in zip(loops, k) if m > 0]
        return np.concatenate(out) if out else np.empty((0, 2))

    def min_radius_of_curvature(self) -> float:
        y = self._samples[0]
        g = self._g(y)
        tau = rot90(g) / norm2(g)[:, None]
        kappa = np.abs(np.einsum("ki,kij,kj->k", tau, self._H(y), tau)) / norm2(g)
        return float(1 / kappa.max()) if kappa.max() > 0 else np.inf


# ----------------------------------------------------------------------------- parametric
class ParametricCurve(Boundary):
    """A closed C2 curve ``c(t)``, ``t`` in ``[0, period)``, counter-clockwise around Omega.

    Subclasses set ``period`` and implement :meth:`point`, :meth:`derivative` and
    :meth:`second_derivative` (for any real ``t``; the base class wraps it into the period).
    The outward normal is ``N = (c'_y, -c'_x) / |c'|``.

    Closest points: the curve is sampled at ``n_samples`` equal parameter steps ``dt``; every
    point gets the candidate samples of :func:`_candidates` (the discrete local minima of the
    sample distances near the smallest one: usually just the nearest sample; the search
    starts from :class:`_SampleHints`) and, for each, a bracketed safeguarded Newton method
    on ``g(t) = c'(t).(c(t) - x) = 0`` in ``[t_i - dt, t_i + dt]`` (both neighbouring sample
    intervals, where ``g`` and ``g'`` come from values cached at the samples) from the root
    of the cubic that interpolates them (:func:`_hermite_root`); the nearest result wins.
    Assumption (dense sampling): the distance to ``x`` is unimodal over any two neighbouring
    sample intervals that hold a local minimum, and the arc between consecutive samples is
    less than 1.5 times their chord; raise ``n_samples`` for curves with features finer than
    ``length / n_samples``.

    Sign: exact and O(1) away from Gamma (see :class:`_Grid`); ``sign((x - pi(x)).N)`` in the
    grid cells that Gamma crosses (exact: the open segment from ``x`` to its closest point
    does not meet Gamma).

    Parameters
    ----------
    n_samples
        Number of samples (at least 64).
    """

    period: float

    def __init__(self, n_samples: int = 4096) -> None:
        if int(n_samples) < 64:
            raise ValueError(f"n_samples must be at least 64, got {n_samples}")
        self.n_samples = int(n_samples)

    @abc.abstractmethod
    def point(self, t: Float) -> Float:
        """Points ``c(t)`` for parameters ``t (m,)``, shape ``(m, 2)``."""

    @abc.abstractmethod
    def derivative(self, t: Float) -> Float:
        """First derivatives ``c'(t)``, shape ``(m, 2)``."""

    @abc.abstractmethod
    def second_derivative(self, t: Float) -> Float:
        """Second derivatives ``c''(t)``, shape ``(m, 2)``."""

    def _c012(self, t: Float) -> tuple[Float, Float, Float]:
        """``c(t), c'(t), c''(t)`` for ``t`` in ``[0, period)`` (one call, for speed)."""
        return self.point(t), self.derivative(t), self.second_derivative(t)

    def _outward(self, t: Float) -> Float:
        d = self.derivative(np.mod(t, self.period))
        return _unit(np.column_stack([d[:, 1], -d[:, 0]]))

    @cached_property
    def _samples(self) -> tuple[Float, Float, cKDTree, Int, Int, float]:
        n = self.n_samples
        t = np.arange(n, dtype=np.float64) * (self.period / n)
        p = np.asarray(self.point(t), dtype=np.float64)
        if not np.isfinite(p).all():
            raise ValueError(f"{type(self).__name__}: the curve has non-finite points")
        if _signed_area(p) <= 0:
            raise ValueError(
                f"{type(self).__name__} runs clockwise: the curve must run counter-clockwise "
                "around the domain"
            )
        prev, nxt = _neighbours([n])
        return t, p, cKDTree(p), prev, nxt, float(_chords(p).max())

    @cached_property
    def _clearance(self) -> tuple[Float, ...]:
        _, p, tree, _, nxt, _ = self._samples
        return _window_clearance(tree, p, nxt)

    @cached_property
    def _hints(self) -> _SampleHints:
        _, p, tree, prev, nxt, h = self._samples
        return _SampleHints(p, tree, prev, nxt, h)

    @cached_property
    def _sample_derivatives(self) -> tuple[Float, ...]:
        """At the samples' parameters ``(n_samples,)`` each: the coordinates of ``c``,
        ``c'`` and ``c''`` and ``|c'|^2``. With them, ``g`` and ``g'`` at the ends of every
        bracket of :meth:`_project` (two samples) cost no evaluation of the curve."""
        t = self._samples[0]
        c, c1, c2 = (np.asarray(v, dtype=np.float64) for v in self._c012(t))
        return c[:, 0], c[:, 1], c1[:, 0], c1[:, 1], c2[:, 0], c2[:, 1], (c1 * c1).sum(axis=1)

    def _project(self, x: Float) -> tuple[Float, Float]:
        """Parameters ``(n,)`` and points ``(n, 2)`` of the closest points of ``x (n, 2)``."""
        if not len(x):
            return np.empty(0), np.empty((0, 2))
        ts, ps, tree, prev, nxt, h = self._samples
        start = self._hints.starts(x)
        pi, si = _candidates(x, tree, ps, prev, nxt, 0.75 * h, self._clearance, start)
        xs, n, T = x[pi], len(ts), self.period

        def ev(t: Float, xx: Float) -> tuple[Float, Float, Float]:
            c, c1, c2 = self._c012(np.mod(t, T))
            r = c - xx
            return (c1 * r).sum(axis=1), (c2 * r).sum(axis=1) + (c1 * c1).sum(axis=1), c

        # The bracket: the neighbouring samples' parameters (continued across the period),
        # where c and c' are known: g there costs no evaluation of the curve.
        il, ih = prev[si], nxt[si]
        lo = ts[il] - np.where(si == 0, T, 0.0)
        hi = ts[ih] + np.where(si == n - 1, T, 0.0)
        cx, cy, d1x, d1y, d2x, d2y, d11 = self._sample_derivatives
        x0, x1 = xs[:, 0], xs[:, 1]
        ax, ay, bx, by = cx[il] - x0, cy[il] - x1, cx[ih] - x0, cy[ih] - x1  # c - x at the ends
        glo = d1x[il] * ax + d1y[il] * ay
        ghi = d1x[ih] * bx + d1y[ih] * by
        t = np.where(ax * ax + ay * ay <= bx * bx + by * by, lo, hi)  # no root: an endpoint
        br = np.flatnonzero((glo <= 0) & (ghi >= 0))
        if br.size:
            xb, lb, hb, b0, b1 = xs[br], lo[br], hi[br], il[br], ih[br]
            dga = d2x[b0] * ax[br] + d2y[b0] * ay[br] + d11[b0]  # g' at the ends
            dgb = d2x[b1] * bx[br] + d2y[b1] * by[br] + d11[b1]
            t0, bound = _hermite_root(glo[br], ghi[br], dga, dgb, lb, hb)
            t0 = np.where(np.isfinite(t0), t0, ts[si][br])
            t[br] = _bracketed_newton(
                lambda tt, i: ev(tt, xb[i])[:2], t0, lb, hb, 8 * _EPS * T, curvature=bound
            )
        t = np.mod(t, T)
        y = self.point(t)
        best = _best(pi, norm2(y - xs))
        return t[best], y[best]

    def _exact_sign(self, x: Float, t: Float, y: Float) -> Float:
        return np.where(((x - y) * self._outward(t)).sum(axis=1) < 0, -1.0, 1.0)

    def sign(self, x: npt.ArrayLike) -> Float:
        x = as_points(x)
        s = self._grid.sign_code(x)
        m = s == 0
        if m.any():
            s[m] = self._exact_sign(x[m], *self._project(x[m]))
        return s

    def project(self, x: npt.ArrayLike) -> tuple[Float, Float]:
        x = as_points(x)
        t, y = self._project(x)
        s = self._grid.sign_code(x)
        m = s == 0
        s[m] = self._exact_sign(x[m], t[m], y[m])
        return s * norm2(x - y), y

    def project_normal(self, x: npt.ArrayLike) -> tuple[Float, Float, Float]:
        x = as_points(x)
        project = type(self).project
        if not _native(self, ParametricCurve, "closest_point", "normal") or project not in (
            ParametricCurve.project,
            Boundary.project,
        ):
            return Boundary.project_normal(self, x)
        if project is Boundary.project:  # the subclass's own sign
            return self._sign_closest_normal(x)
        t, y = self._project(x)
        s = self._grid.sign_code(x)
        m = s == 0
        s[m] = self._exact_sign(x[m], t[m], y[m])
        return s * norm2(x - y), y, self._outward(t)

    def closest_normal(self, x: Float) -> tuple[Float, Float]:
        if not _native(self, ParametricCurve, "closest_point", "normal"):
            return Boundary.closest_normal(self, x)
        t, y = self._project(x)
        return y, self._outward(t)

    def closest_point(self, x: npt.ArrayLike) -> Float:
        return self._project(as_points(x))[1]

    def normal(self, y: npt.ArrayLike) -> Float:
        return self._outward(self._project(as_points(y))[0])

    def bounding_box(self) -> Float:
        return self._bbox.copy()

    @cached_property
    def _bbox(self) -> Float:
        p, h = self._samples[1], self._samples[5]
        return np.array([p.min(axis=0) - h, p.max(axis=0) + h])

    def sample(self, n: int) -> Float:
        return self.point(self._sample_parameters(n))

    def _sample_parameters(self, n: int) -> Float:
        """Parameters of ``n`` points about equally spaced in arc length, ``(n,)``."""
        t, p = self._samples[:2]
        s = np.concatenate([[0.0], np.cumsum(_chords(p))])
        u = np.arange(n) * (s[-1] / max(n, 1))
        return np.mod(np.interp(u, s, np.append(t, self.period)), self.period)

    def _loops_normals(self, spacing: float) -> tuple[list[Float], list[Float]]:
        if not _native(self, ParametricCurve, "sample", "_loops", "normal"):
            return Boundary._loops_normals(self, spacing)
        cached = self.__dict__.get("_last_loops")  # a moving body asks for the same spacing
        if cached is None or cached[0] != spacing:
            n = 1024  # as Boundary._loops; the normals from the parameters, not by projection
            while True:
                t = self._sample_parameters(n)
                p = self.point(t)
                longest = float(_chords(p).max())
                if longest <= spacing:
                    break
                n = int(np.ceil(n * longest / spacing * 1.1))
            cached = self.__dict__["_last_loops"] = (spacing, p, self._outward(t))
        return [cached[1].copy()], [cached[2].copy()]

    def min_radius_of_curvature(self) -> float:
        t = np.arange(4 * self.n_samples, dtype=np.float64) * (self.period / (4 * self.n_samples))
        d1, d2 = self.derivative(t), self.second_derivative(t)
        kappa = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / norm2(d1) ** 3
        return float(1 / kappa.max()) if kappa.max() > 0 else np.inf


class PeriodicSpline(ParametricCurve):
    """Closed periodic cubic spline through ``points (m, 2)``, chord-length parametrised.

    A last point repeating the first is dropped. Clockwise points are reversed with a
    :class:`UserWarning` when ``orientation="auto"`` and rejected when ``"ccw"``. Raises
    :class:`ValueError` for fewer than 4 distinct points, non-finite or repeated consecutive
    points, and for a spline that intersects itself (tested on a dense polyline).

    Parameters
    ----------
    points
        Interpolated points ``(m, 2)``, in order around the domain.
    orientation
        ``"auto"`` (reverse clockwise points) or ``"ccw"`` (require counter-clockwise).
    n_samples
        See :class:`ParametricCurve`.
    """

    def __init__(
        self, points: npt.ArrayLike, orientation: str = "auto", n_samples: int = 4096
    ) -> None:
        super().__init__(n_samples)
        if orientation not in ("auto", "ccw"):
            raise ValueError(f'orientation must be "auto" or "ccw", got {orientation!r}')
        p = as_points(points, "points")
        if len(p) > 1 and (p[0] == p[-1]).all():
            p = p[:-1]
        distinct = len(np.unique(p, axis=0))
        if distinct < 4:
            raise ValueError(f"a periodic spline needs at least 4 distinct points, got {distinct}")
        dup = np.flatnonzero((np.roll(p, -1, axis=0) == p).all(axis=1))
        if dup.size:
            i = int(dup[0])
            raise ValueError(
                f"points {i} and {(i + 1) % len(p)} coincide (at {p[i].tolist()}): "
                "remove the repeated point"
            )
        self._build(p)
        if _signed_area(self.point(np.linspace(0, self.period, 2048, endpoint=False))) < 0:
            if orientation == "ccw":
                raise ValueError(
                    "the points run clockwise: reverse them (points[::-1]) or use "
                    'orientation="auto"'
                )
            warnings.warn(
                "PeriodicSpline: the points run clockwise; they were reversed so that the "
                "curve runs counter-clockwise around the domain",
                UserWarning,
                stacklevel=2,
            )
            self._build(p[::-1].copy())
        self._check_simple()

    def _build(self, p: Float) -> None:
        closed = np.vstack([p, p[:1]])
        knots = np.concatenate([[0.0], np.cumsum(norm2(np.diff(closed, axis=0)))])
        self.points = p
        self.period = float(knots[-1])
        self._spline = CubicSpline(knots, closed, bc_type="periodic", axis=0)

    def _check_simple(self) -> None:
        """Raise if non-adjacent edges of a dense polyline of the spline intersect."""
        m = max(self.n_samples, 16 * len(self.points))
        a = self.point(np.arange(m, dtype=np.float64) * (self.period / m))
        b = np.roll(a, -1, axis=0)
        pairs = cKDTree((a + b) / 2).query_pairs(float(norm2(b - a).max()), output_type="ndarray")
        i, j = pairs[:, 0], pairs[:, 1]
        gap = (j - i) % m
        i, j = i[(gap > 1) & (gap < m - 1)], j[(gap > 1) & (gap < m - 1)]

        def side(p: Float, q: Float, r: Float) -> Float:
            return cross2(q - p, r - p)

        hit = (side(a[i], b[i], a[j]) * side(a[i], b[i], b[j]) <= 0) & (
            side(a[j], b[j], a[i]) * side(a[j], b[j], b[i]) <= 0
        )  # and bounding boxes overlap (collinear edges):
        hit &= (np.minimum(a[i], b[i]) <= np.maximum(a[j], b[j])).all(axis=1)
        hit &= (np.minimum(a[j], b[j]) <= np.maximum(a[i], b[i])).all(axis=1)
        if hit.any():
            k = int(np.argmax(hit))
            x, y = (a[i[k]] + b[i[k]]) / 2
            raise ValueError(
                f"the spline through the points intersects itself near ({x:.6g}, {y:.6g}): "
                "check the order of the points"
            )

    def _c012(self, t: Float) -> tuple[Float, Float, Float]:
        k = self._spline.x
        i = np.clip(np.searchsorted(k, t, side="right") - 1, 0, len(k) - 2)
        c = self._spline.c[:, i]  # (4, m, 2) coefficients of the intervals
        u = (t - k[i])[:, None]
        return (
            ((c[0] * u + c[1]) * u + c[2]) * u + c[3],
            (3 * c[0] * u + 2 * c[1]) * u + c[2],
            6 * c[0] * u + 2 * c[1],
        )

    def point(self, t: Float) -> Float:
        return self._spline(np.mod(t, self.period))

    def derivative(self, t: Float) -> Float:
        return self._spline(np.mod(t, self.period), 1)

    def second_derivative(self, t: Float) -> Float:
        return self._spline(np.mod(t, self.period), 2)

    @classmethod
    def from_file(cls, path: str | Path, **kwargs: object) -> PeriodicSpline:
        """Spline through the points of a file (keyword arguments go to the constructor).

        CSV or text: two columns ``x, y`` separated by a comma or whitespace, with an optional
        header line and ``#`` comments. JSON (``.json`` or text starting with ``[``/``{``): a
        list of ``[x, y]`` pairs or ``{"points": [[x, y], ...]}``.
        """
        path = Path(path)
        text = path.read_text()
        if path.suffix.lower() == ".json" or text.lstrip()[:1] in ("[", "{"):
            data = json.loads(text)
            if isinstance(data, dict):
                if "points" not in data:
                    raise ValueError(f'{path}: JSON object without a "points" entry')
                data = data["points"]
            pts = np.asarray(data, dtype=np.float64)
        else:
            rows = [r.split("#")[0].replace(",", " ").split() for r in text.splitlines()]
            rows = [r for r in rows if r]
            for k in range(2):  # a first line that is not numbers is a header
                try:
                    pts = np.array([[float(v) for v in r] for r in rows[k:]] or np.empty((0, 2)))
                    break
                except ValueError as e:
                    if k:
                        raise ValueError(f"{path}: {e}") from None
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise ValueError(f"{path}: expected two columns x, y, got an array {pts.shape}")
        return cls(pts, **kwargs)  # type: ignore[arg-type]


class PolarCurve(ParametricCurve):
    """Star-shaped curve ``c(theta) = center + r(theta) (cos theta, sin theta)``.

    ``r``, ``dr``, ``d2r`` map angles ``(m,)`` to ``(m,)``; ``r`` must be positive (checked on
    ``n_samples`` angles). The sign is the exact test ``|x - center| < r(atan2)``.

    Parameters
    ----------
    r, dr, d2r
        Radius and its first two derivatives, vectorised over angles.
    center
        Pole ``(2,)``.
    n_samples
        See :class:`ParametricCurve`.
    """

    def __init__(
        self,
        r: ArrayFn,
        dr: ArrayFn,
        d2r: ArrayFn,
        center: npt.ArrayLike = (0.0, 0.0),
        n_samples: int = 4096,
    ) -> None:
        super().__init__(n_samples)
        self.r, self.dr, self.d2r = r, dr, d2r
        self.center = _vector(center, "center")
        self.period = 2 * np.pi
        th = np.arange(self.n_samples, dtype=np.float64) * (2 * np.pi / self.n_samples)
        rv = _call(r, th, th.shape)
        bad = np.flatnonzero(~(np.isfinite(rv) & (rv > 0)))
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"r must be positive and finite: r({th[i]:.6g}) = {rv[i]}")

    def _frame(self, t: Float) -> tuple[Float, Float]:
        u = np.column_stack([np.cos(t), np.sin(t)])
        return u, rot90(u)

    def _c012(self, t: Float) -> tuple[Float, Float, Float]:
        u, v = self._frame(t)  # once for the three (the formulas of point, derivative, ...)
        r, dr, d2r = (_call(f, t, t.shape)[:, None] for f in (self.r, self.dr, self.d2r))
        return self.center + r * u, dr * u + r * v, (d2r - r) * u + 2 * dr * v

    def point(self, t: Float) -> Float:
        return self.center + _call(self.r, t, t.shape)[:, None] * self._frame(t)[0]

    def derivative(self, t: Float) -> Float:
        u, v = self._frame(t)
        return _call(self.dr, t, t.shape)[:, None] * u + _call(self.r, t, t.shape)[:, None] * v

    def second_derivative(self, t: Float) -> Float:
        u, v = self._frame(t)
        r, dr, d2r = (_call(f, t, t.shape)[:, None] for f in (self.r, self.dr, self.d2r))
        return (d2r - r) * u + 2 * dr * v

    def sign(self, x: npt.ArrayLike) -> Float:
        d = as_points(x) - self.center
        th = np.arctan2(d[:, 1], d[:, 0])
        return np.where(norm2(d) < _call(self.r, th, th.shape), -1.0, 1.0)

    project = Boundary.project

    def onto_gamma(self, x: Float) -> tuple[Float, Float]:
        """Points of Gamma near points ``x (n, 2)`` close to it and the outward normals
        there: the point ``c(theta)`` of Gamma on the ray from the pole through ``x`` (one
        evaluation of ``r`` and ``dr``, no search: about a tenth of the cost of a closest
        point). Where the ray meets Gamma at a grazing angle (the point farther from ``x``
        than :data:`ONTO_REACH` times its distance from the tangent line there), one
        Newton step along Gamma moves it onto the normal line through ``x``; a point still
        that far gets its closest point."""
        names = ("point", "derivative", "closest_point", "normal", "closest_normal")
        if not _native(self, PolarCurve, *names):
            return Boundary.onto_gamma(self, x)
        x = as_points(x)
        d = x - self.center
        t = np.mod(np.arctan2(d[:, 1], d[:, 0]), self.period)
        y, c1 = self._point_derivative(t)
        n = _unit(np.column_stack([c1[:, 1], -c1[:, 0]]))  # as _outward()
        bad = np.flatnonzero(~self._near(x, y, n))
        if bad.size:  # Newton on cross(c(t) - x, n) = 0 (its derivative is -|c'(t)|)
            xb, nb = x[bad], n[bad]
            t = t[bad] + cross2(y[bad] - xb, nb) / norm2(c1[bad])
            yb, c1 = self._point_derivative(np.mod(t, self.period))
            nb = _unit(np.column_stack([c1[:, 1], -c1[:, 0]]))
            far = np.flatnonzero(~self._near(xb, yb, nb))
            if far.size:
                yb[far], nb[far] = self.closest_normal(xb[far])
            y[bad], n[bad] = yb, nb
        return y, n

    def _point_derivative(self, t: Float) -> tuple[Float, Float]:
        """``c(t)`` and ``c'(t)`` ``(m, 2)`` each, with one evaluation of ``r`` and ``dr``."""
        u, v = self._frame(t)
        r, dr = (_call(f, t, t.shape)[:, None] for f in (self.r, self.dr))
        return self.center + r * u, dr * u + r * v  # as point() and derivative()

    def _near(self, x: Float, y: Float, n: Float) -> Bool:
        """Whether the points ``y`` of Gamma (normals ``n``) are within :data:`ONTO_REACH`
        times the distance of ``x`` from their tangent lines (finite)."""
        off = x - y
        scale = float(norm2(self._bbox[1:] - self._bbox[:1])[0])
        with np.errstate(invalid="ignore"):
            reach = ONTO_REACH * np.abs((off * n).sum(axis=1)) + 1e-12 * scale
            return np.isfinite(n).all(axis=1) & (norm2(off) <= reach)


class Ellipse(ParametricCurve):
    """Omega = the open ellipse of semi-axes ``a`` (along the rotated x axis) and ``b``.

    The ellipse is rotated by ``angle`` radians about ``center``; ``t`` is the angular
    parameter of ``(a cos t, b sin t)``. The sign is analytic. The closest point is found by
    a bracketed Newton method on ``t`` in the quadrant of the point, where it is the unique
    stationary point: global and exact for every point.

    Parameters
    ----------
    center
        Centre ``(2,)``.
    a, b
        Semi-axes ``> 0``.
    angle
        Rotation in radians (counter-clockwise).
    n_samples
        See :class:`ParametricCurve` (used by :meth:`near` and :meth:`sample`).
    """

    def __init__(
        self, center: npt.ArrayLike, a: float, b: float, angle: float = 0.0, n_samples: int = 4096
    ) -> None:
        super().__init__(n_samples)
        self.center = _vector(center, "center")
        self.a, self.b = positive(a, "a"), positive(b, "b")
        self.angle, self.period = float(angle), 2 * np.pi
        self._cs = np.cos(self.angle), np.sin(self.angle)

    def point(self, t: Float) -> Float:
        p = np.column_stack([self.a * np.cos(t), self.b * np.sin(t)])
        return self.center + _rotate(p, *self._cs)

    def derivative(self, t: Float) -> Float:
        return _rotate(np.column_stack([-self.a * np.sin(t), self.b * np.cos(t)]), *self._cs)

    def second_derivative(self, t: Float) -> Float:
        return self.center - self.point(t)

    def _local(self, x: npt.ArrayLike) -> Float:
        return _rotate(as_points(x) - self.center, self._cs[0], -self._cs[1])

    def sign(self, x: npt.ArrayLike) -> Float:
        p = self._local(x)
        return np.where((p[:, 0] / self.a) ** 2 + (p[:, 1] / self.b) ** 2 < 1, -1.0, 1.0)

    project = Boundary.project

    def _project(self, x: Float) -> tuple[Float, Float]:
        p = self._local(x)
        q = np.maximum(np.abs(p), np.finfo(np.float64).tiny)  # first quadrant, off the axes
        a, b, e = self.a, self.b, self.b**2 - self.a**2

        def g(t: Float, i: Int) -> tuple[Float, Float]:
            s, c = np.sin(t), np.cos(t)
            return e * s * c + a * q[i, 0] * s - b * q[i, 1] * c, (
                e * (c * c - s * s) + a * q[i, 0] * c + b * q[i, 1] * s
            )

        n = len(p)
        t0 = np.arctan2(a * q[:, 1], b * q[:, 0])
        t = _bracketed_newton(g, t0, np.zeros(n), np.full(n, np.pi / 2), 4 * _EPS)
        t = np.where(p[:, 0] < 0, np.pi - t, t)
        t = np.mod(np.where(p[:, 1] < 0, -t, t), self.period)
        return t, self.point(t)

    def min_radius_of_curvature(self) -> float:
        return min(self.a, self.b) ** 2 / max(self.a, self.b)


# ----------------------------------------------------------------------------- compositions
class RigidMotion(Boundary):
    """``base`` rotated about ``center``, then translated by ``translation``.

    ``y -> center + R (y - center) + translation``; everything is delegated to ``base``
    through the inverse motion (normals and tangents rotated). In 2D ``R`` is the rotation by
    ``angle``; for a surface (``base.gdim == 3``) it is ``rotation``, or the rotation by
    ``angle`` about the z axis when ``rotation`` is None.

    Parameters
    ----------
    base
        The boundary (or surface) in its reference position.
    angle
        Rotation in radians (counter-clockwise; about the z axis in 3D).
    center
        Centre of the rotation ``(gdim,)``; the default (zeros) is the origin in 3D too.
    translation
        Translation ``(gdim,)`` applied after the rotation; the default is no translation.
    rotation
        3D only (then ``angle`` must be 0): a rotation matrix ``(3, 3)``, a rotation vector
        ``(3,)`` (axis times angle) or a pair ``(axis, angle)``.
    """

    def __init__(
        self,
        base: Boundary,
        angle: float = 0.0,
        center: npt.ArrayLike = (0.0, 0.0),
        translation: npt.ArrayLike = (0.0, 0.0),
        *,
        rotation: object = None,
    ) -> None:
        self.base = base
        self.gdim = dim = int(getattr(base, "gdim", 2))
        self.angle = float(angle)
        if dim == 2:
            if rotation is not None:
                raise ValueError("rotation is for surfaces (3D): give a planar motion's angle")
            self.center = _vector(center, "center")
            self.translation = _vector(translation, "translation")
            self._cs = np.cos(self.angle), np.sin(self.angle)
            c, s = self._cs
            self.rotation = np.array([[c, -s], [s, c]])
            return
        if rotation is not None and self.angle != 0:
            raise ValueError("give either angle (about the z axis) or rotation, not both")
        self.center = self._vector3(center, "center")
        self.translation = self._vector3(translation, "translation")
        self.rotation = _rotation_matrix(
            rotation if rotation is not None else ((0.0, 0.0, 1.0), self.angle)
        )

    @staticmethod
    def _vector3(v: npt.ArrayLike, name: str) -> Float:
        """A 3D vector; two zeros (the planar default) are the zero vector."""
        a = np.asarray(v, dtype=np.float64).reshape(-1)
        if a.shape == (2,) and (a == 0).all():
            return np.zeros(3)
        return _vector(a, name, 3)

    def moved(
        self,
        angle: float = 0.0,
        translation: npt.ArrayLike = (0.0, 0.0),
        *,
        rotation: object = None,
    ) -> RigidMotion:
        """The same base and centre under another motion (absolute, not composed)."""
        if self.gdim == 2:
            return RigidMotion(self.base, angle, self.center, translation)
        return RigidMotion(self.base, angle, self.center, translation, rotation=rotation)

    def _to_base(self, x: npt.ArrayLike) -> Float:
        if self.gdim == 2:
            x = as_points(x) - self.center - self.translation
            return self.center + _rotate(x, self._cs[0], -self._cs[1])
        return self.center + (as_points(x, dim=3) - self.center - self.translation) @ (
            self.rotation
        )

    def _from_base(self, y: Float) -> Float:
        if self.gdim == 2:
            return self.center + _rotate(y - self.center, *self._cs) + self.translation
        return self.center + (y - self.center) @ self.rotation.T + self.translation

    def _turn(self, v: Float) -> Float:
        """Vectors ``(n, gdim)`` (or ``(n, k, gdim)``) rotated by the motion."""
        if self.gdim == 2:
            return _rotate(v, *self._cs)
        return v @ self.rotation.T

    def sign(self, x: npt.ArrayLike) -> Float:
        return self.base.sign(self._to_base(x))

    def closest_point(self, x: npt.ArrayLike) -> Float:
        return self._from_base(self.base.closest_point(self._to_base(x)))

    def project(self, x: npt.ArrayLike) -> tuple[Float, Float]:
        phi, y = self.base.project(self._to_base(x))
        return phi, self._from_base(y)

    def project_normal(self, x: npt.ArrayLike) -> tuple[Float, Float, Float]:
        if not _native(self, RigidMotion, "project", "normal"):
            return Boundary.project_normal(self, x)
        phi, y, n = self.base.project_normal(self._to_base(x))
        return phi, self._from_base(y), self._turn(n)

    def closest_normal(self, x: Float) -> tuple[Float, Float]:
        if not _native(self, RigidMotion, "closest_point", "normal"):
            return Boundary.closest_normal(self, x)
        y, n = self.base.closest_normal(self._to_base(x))
        return self._from_base(y), self._turn(n)

    def onto_gamma(self, x: Float) -> tuple[Float, Float]:
        if not _native(self, RigidMotion, "closest_point", "normal", "closest_normal"):
            return Boundary.onto_gamma(self, x)
        y, n = self.base.onto_gamma(self._to_base(x))
        return self._from_base(y), self._turn(n)

    def normal(self, y: npt.ArrayLike) -> Float:
        return self._turn(self.base.normal(self._to_base(y)))

    def tangent(self, y: npt.ArrayLike) -> Float:
        return self._turn(self.base.tangent(self._to_base(y)))

    def tangent_basis(self, y: npt.ArrayLike) -> Float:
        if self.gdim == 2:
            return self.tangent(y)[:, None, :]
        return self._turn(self.base.tangent_basis(self._to_base(y)))

    def near(self, x: npt.ArrayLike, distance: float | npt.ArrayLike) -> Bool:
        return self.base.near(self._to_base(x), distance)

    def _lower_bound(self, x: Float) -> Float:
        return self.base._lower_bound(self._to_base(x))

    def bounding_box(self) -> Float:
        if self.gdim == 2:
            (x0, y0), (x1, y1) = self.base.bounding_box()
            c = self._from_base(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]))
        else:
            box = np.asarray(self.base.bounding_box(), dtype=np.float64)
            corners = np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, -1)
            c = self._from_base(box[corners.T, [0, 1, 2]])
        pad = 4 * _EPS * np.abs(c).max()
        return np.array([c.min(axis=0) - pad, c.max(axis=0) + pad])

    def sample(self, n: int) -> Float:
        return self._from_base(self.base.sample(n))

    def min_radius_of_curvature(self) -> float:
        return self.base.min_radius_of_curvature()

    @property
    def euler_characteristic(self) -> int:
        """Euler characteristic of the base surface (3D)."""
        return int(self.base.euler_characteristic)  # type: ignore[attr-defined]

    @property
    def num_components(self) -> int:
        """Number of connected components of the base surface (3D)."""
        return int(self.base.num_components)  # type: ignore[attr-defined]

    def _length(self) -> float:
        return self.base._length()

    def _measure(self) -> float:
        return self.base._measure()

    def _loops(self, spacing: float) -> list[Float]:
        return [self._from_base(q) for q in self.base._loops(spacing)]

    def _loops_normals(self, spacing: float) -> tuple[list[Float], list[Float]]:
        loops, normals = self.base._loops_normals(spacing)
        return [self._from_base(q) for q in loops], [_rotate(n, *self._cs) for n in normals]


class Domain(Boundary):
    """Omega = inside(``container``) minus the closures of the ``bodies``.

    ``container=None`` is the whole plane or space (the background mesh clips it). Each body
    is a :class:`Boundary` whose own inside is the solid. The components are all curves
    (``gdim = 2``) or all surfaces (``gdim = 3``,
    :class:`~dolfinx_universal.boundaries.surfaces.Surface`);
    :attr:`gdim` is theirs. The components are assumed pairwise disjoint and separated
    (bodies inside the container, apart from each other and from it), so the distance to
    Gamma is the smallest distance to a component. Sign rule:
    ``sign(x) = -1`` iff ``container.sign(x) == -1`` and ``body.sign(x) == +1`` for every
    body; a point exactly on a body's curve (measure zero) therefore counts as in Omega.
    Normals point out of Omega: into the bodies.

    Parameters
    ----------
    container
        Boundary of the region containing Omega, or None (the whole plane).
    bodies
        Boundaries of the solids removed from it.
    """

    def __init__(self, container: Boundary | None = None, bodies: Sequence[Boundary] = ()) -> None:
        self.container = container
        self.bodies = tuple(bodies)
        if container is None and not self.bodies:
            raise ValueError("a Domain needs a container or at least one body")
        for b, _ in self.components:
            if not isinstance(b, Boundary):
                raise TypeError(f"Domain components must be Boundary objects, got {type(b)}")
        dims = {int(getattr(b, "gdim", 2)) for b, _ in self.components}
        if len(dims) != 1:
            raise ValueError("the components of a Domain must all be curves or all surfaces")
        self.gdim = dims.pop()

    @property
    def components(self) -> list[tuple[Boundary, bool]]:
        """``(boundary, is_body)`` pairs: the container first (if any), then the bodies."""
        first = [(self.container, False)] if self.container is not None else []
        return first + [(b, True) for b in self.bodies]

    def nearest_component(self, x: npt.ArrayLike) -> npt.NDArray[np.intp]:
        """Index in :attr:`components` of the component nearest to each point ``(n,)``
        (ties: the first, the container)."""
        pts = np.asarray(x, dtype=np.float64)
        dist = [np.abs(c.signed_distance(pts)) for c, _ in self.components]
        return np.argmin(np.reshape(dist, (len(dist), len(pts))), axis=0)

    @property
    def euler_characteristic(self) -> int:
        """Euler characteristic of Gamma: the sum over the components (surfaces only).

        Checks compare it per component: group the faces of the conforming mesh on Gamma by
        :meth:`component_index` of their points and compare each group with
        ``components[k][0].euler_characteristic``.
        """
        return sum(int(b.euler_characteristic) for b, _ in self.components)  # type: ignore

    @property
    def num_components(self) -> int:
        """Number of connected components of Gamma (surfaces only: theirs summed)."""
        return sum(int(b.num_components) for b, _ in self.components)  # type: ignore

    def sign(self, x: npt.ArrayLike) -> Float:
        x = as_points(x, dim=self.gdim)
        s = self.container.sign(x) if self.container is not None else np.full(len(x), -1.0)
        for b in self.bodies:
            m = np.flatnonzero(s < 0)
            s[m[b.sign(x[m]) < 0]] = 1.0
        return s

    def _closest(
        self, x: Float, normals: bool = False, onto: bool = False
    ) -> tuple[Int, Float, Float, Float | None]:
        """Closest component index ``(n,)``, closest point ``(n, gdim)``, distance ``(n,)``
        and, with ``normals``, the outward normals of Omega there ``(n, gdim)`` (else None).

        Each point is projected onto the component with the smallest distance lower bound,
        then onto every other component whose lower bound beats the best distance so far.
        With ``onto`` (and ``normals``), the components' :meth:`onto_gamma` instead of their
        closest points: a point of the nearest component, near ``x``.
        """
        comps = self.components
        if not len(x):
            e = np.empty((0, self.gdim))
            return np.zeros(0, dtype=np.intp), e, np.zeros(0), e.copy() if normals else None
        if len(comps) == 1:  # no lower bounds needed
            b, body = comps[0]
            if normals:
                y, n = b.onto_gamma(x) if onto else b.closest_normal(x)
                return np.zeros(len(x), dtype=np.intp), y, _normd(x - y), -n if body else n
            y = b.closest_point(x)
            return np.zeros(len(x), dtype=np.intp), y, _normd(x - y), None
        lb = np.array([b._lower_bound(x) for b, _ in comps]).reshape(len(comps), len(x))
        first = lb.argmin(axis=0) if len(x) else np.zeros(0, dtype=np.intp)
        idx, y, d = first.copy(), np.empty((len(x), self.gdim)), np.full(len(x), np.inf)
        out: Float | None = np.empty((len(x), self.gdim)) if normals else None
        for rnd in range(2):
            for k, (b, body) in enumerate(comps):
                m = np.flatnonzero((first == k) if rnd == 0 else (lb[k] < d) & (first != k))
                if m.size:
                    if normals:
                        yk, nk = b.onto_gamma(x[m]) if onto else b.closest_normal(x[m])
                    else:
                        yk = b.closest_point(x[m])
                    dk = _normd(x[m] - yk)
                    better = dk < d[m]
                    m = m[better]
                    y[m], d[m] = yk[better], dk[better]
                    if out is not None:
                        out[m] = -nk[better] if body else nk[better]
                    if rnd:
                        idx[m] = k
        return idx, y, d, out

    def component_index(self, y: npt.ArrayLike) -> Int:
        """Index ``(n,)`` into :attr:`components` of the component closest to each point.

        For points ``y (n, gdim)`` on Gamma (e.g. closest points, or the vertices of the
        conforming mesh on Gamma) it is the component they lie on.
        """
        return self._closest(as_points(y, dim=self.gdim))[0]

    def closest_point(self, x: npt.ArrayLike) -> Float:
        return self._closest(as_points(x, dim=self.gdim))[1]

    def project(self, x: npt.ArrayLike) -> tuple[Float, Float]:
        x = as_points(x, dim=self.gdim)
        _, y, d, _ = self._closest(x)
        return self.sign(x) * d, y

    def project_normal(self, x: npt.ArrayLike) -> tuple[Float, Float, Float]:
        x = as_points(x, dim=self.gdim)
        if not _native(self, Domain, "project", "closest_point", "normal"):
            return Boundary.project_normal(self, x)
        _, y, d, n = self._closest(x, normals=True)
        return self.sign(x) * d, y, n  # type: ignore[return-value]

    def closest_normal(self, x: Float) -> tuple[Float, Float]:
        _, y, _, n = self._closest(x, normals=True)
        return y, n  # type: ignore[return-value]

    def onto_gamma(self, x: Float) -> tuple[Float, Float]:
        if not _native(self, Domain, "closest_point", "normal", "closest_normal"):
            return Boundary.onto_gamma(self, x)
        _, y, _, n = self._closest(x, normals=True, onto=True)
        return y, n  # type: ignore[return-value]

    def normal(self, y: npt.ArrayLike) -> Float:
        return self._closest(as_points(y, dim=self.gdim), normals=True)[3]  # type: ignore

    def near(self, x: npt.ArrayLike, distance: float | npt.ArrayLike) -> Bool:
        x = as_points(x, dim=self.gdim)
        out = np.zeros(len(x), dtype=bool)
        for b, _ in self.components:
            out |= b.near(x, distance)
        return out

    def _lower_bound(self, x: Float) -> Float:
        bounds: list[Float] = [b._lower_bound(x) for b, _ in self.components]
        return np.min(bounds, axis=0)

    def bounding_box(self) -> Float:
        boxes = np.array([b.bounding_box() for b, _ in self.components])
        return np.array([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)])

    def sample(self, n: int) -> Float:
        comps = [b for b, _ in self.components]
        k = _split(n, [b._measure() for b in comps])
        return np.concatenate([b.sample(m) for b, m in zip(comps, k)] + [np.empty((0, self.gdim))])

    def min_radius_of_curvature(self) -> float:
        return min(b.min_radius_of_curvature() for b, _ in self.components)

    def _length(self) -> float:
        return sum(b._length() for b, _ in self.components)

    def _measure(self) -> float:
        return sum(b._measure() for b, _ in self.components)

    def _loops(self, spacing: float) -> list[Float]:
        """The loops of every component (container first), each as that component gives it."""
        return [q for b, _ in self.components for q in b._loops(spacing)]

    def _loops_normals(self, spacing: float) -> tuple[list[Float], list[Float]]:
        loops: list[Float] = []
        normals: list[Float] = []
        for b, body in self.components:
            q, n = b._loops_normals(spacing)
            loops += q
            normals += [-v if body else v for v in n]  # out of Omega: into the bodies
        return loops, normals
