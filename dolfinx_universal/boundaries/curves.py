"""Immersed boundaries Gamma of planar domains: circles, level sets, parametric curves
(periodic splines, polar curves, ellipses)."""

from __future__ import annotations

import abc
import json
import warnings
from functools import cached_property
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.interpolate import CubicSpline
from scipy.spatial import cKDTree

from dolfinx_universal.boundaries.base import ONTO_REACH, Boundary, native, onto_or_closest
from dolfinx_universal.boundaries.curve_samples import (
    SampleHints,
    candidates,
    hermite_root,
    neighbours,
    window_clearance,
)
from dolfinx_universal.boundaries.grid import chords
from dolfinx_universal.boundaries.numerics import (
    EPS,
    ArrayFn,
    best_pairs,
    bracketed_newton,
    call,
    distances,
    rotate,
    split,
    unit,
    vector,
)
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
    "Circle",
    "Ellipse",
    "ImplicitCurve",
    "ParametricCurve",
    "PeriodicSpline",
    "PolarCurve",
]


def _signed_area(p: Float) -> float:
    q = np.roll(p, -1, axis=0)
    return 0.5 * float((p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]).sum())


def _resample(loop: Float, n: int) -> Float:
    """``n`` points equally spaced in arc length along the closed polyline ``loop``."""
    closed = np.vstack([loop, loop[:1]])
    s = np.concatenate([[0.0], np.cumsum(chords(loop))])
    u = np.arange(n) * (s[-1] / n)
    return np.column_stack([np.interp(u, s, closed[:, 0]), np.interp(u, s, closed[:, 1])])


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
        self.center = vector(center, "center")
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
        if not native(self, Circle, "closest_point", "normal"):
            return Boundary.closest_normal(self, x)
        u = self._direction(x)
        return self.center + self.radius * u, u

    def near(self, x: npt.ArrayLike, distance: float | npt.ArrayLike) -> Bool:
        x = as_points(x)
        return self.lower_bound(x) <= distances(distance, len(x))

    def lower_bound(self, x: Float) -> Float:
        return np.abs(norm2(x - self.center) - self.radius)

    def bounding_box(self) -> Float:
        r = self.radius * (1 + 4 * EPS)
        return np.array([self.center - r, self.center + r])

    def sample(self, n: int) -> Float:
        t = np.arange(n) * (2 * np.pi / max(n, 1))
        return self.center + self.radius * np.column_stack([np.cos(t), np.sin(t)])

    def min_radius_of_curvature(self) -> float:
        return self.radius

    def length(self) -> float:
        return 2 * np.pi * self.radius


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
        return self._orient * call(self._f, y, (len(y),), "phi")

    def _g(self, y: Float) -> Float:
        return self._orient * call(self._gradf, y, (len(y), 2), "grad")

    def _H(self, y: Float) -> Float:
        if self._hessf is not None:
            return self._orient * call(self._hessf, y, (len(y), 2, 2), "hess")
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
        :data:`~dolfinx_universal.boundaries.base.ONTO_REACH` times Newton's first estimate of
        the offset, or not on Gamma to the closest points' tolerance, get their closest
        points."""
        if not native(self, ImplicitCurve, "closest_point", "normal", "closest_normal"):
            return Boundary.onto_gamma(self, x)
        x = as_points(x)
        y, estimate = self._newton_onto(x, 8)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(y).all(axis=1)
            ok &= norm2(y - x) <= ONTO_REACH * estimate + 1e-12 * self._scale
        y = np.where(ok[:, None], y, x)
        return onto_or_closest(self, x, y, ok, self._s(y), self._g(y), self._scale)

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

    def loops(self, spacing: float) -> list[Float]:
        if not np.isfinite(spacing):
            return self._base_loops
        out = []
        for q in self._base_loops:
            n = max(8, int(np.ceil(chords(q).sum() / spacing * 1.1)))
            while True:
                p = self._to_curve(_resample(q, n))
                longest = float(chords(p).max())
                if longest <= spacing:
                    break
                n = int(np.ceil(n * longest / spacing * 1.1))
            out.append(p)
        return out

    @cached_property
    def _samples(self) -> tuple[Float, cKDTree, Int, Int, float]:
        loops = self.loops(self.length() / self.n_samples)
        pts = np.concatenate(loops)
        prev, nxt = neighbours([len(q) for q in loops])
        return pts, cKDTree(pts), prev, nxt, max(float(chords(q).max()) for q in loops)

    @cached_property
    def _clearance(self) -> tuple[Float, ...]:
        pts, tree, _, nxt, _ = self._samples
        return window_clearance(tree, pts, nxt)

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
        pi, si = candidates(x, tree, pts, prev, nxt, 0.75 * h, self._clearance)
        y, ok = self._newton(x[pi], pts[si], h)
        best = best_pairs(pi, np.where(ok, norm2(y - x[pi]), np.inf))
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
        return unit(g)

    def bounding_box(self) -> Float:
        return self._box.copy()

    def sample(self, n: int) -> Float:
        loops = self._base_loops
        k = split(n, [chords(q).sum() for q in loops])
        out = [self._to_curve(_resample(q, m)) for q, m in zip(loops, k) if m > 0]
        return np.concatenate(out) if out else np.empty((0, 2))

    def min_radius_of_curvature(self) -> float:
        y = self._samples[0]
        g = self._g(y)
        tau = rot90(g) / norm2(g)[:, None]
        kappa = np.abs(np.einsum("ki,kij,kj->k", tau, self._H(y), tau)) / norm2(g)
        return float(1 / kappa.max()) if kappa.max() > 0 else np.inf


class ParametricCurve(Boundary):
    """A closed C2 curve ``c(t)``, ``t`` in ``[0, period)``, counter-clockwise around Omega.

    Subclasses set ``period`` and implement :meth:`point`, :meth:`derivative` and
    :meth:`second_derivative` (for any real ``t``; the base class wraps it into the period).
    The outward normal is ``N = (c'_y, -c'_x) / |c'|``.

    Closest points: the curve is sampled at ``n_samples`` equal parameter steps ``dt``; every
    point gets the candidate samples of
    :func:`~dolfinx_universal.boundaries.curve_samples.candidates` (the discrete local minima
    of the sample distances near the smallest one: usually just the nearest sample; the
    search starts from :class:`~dolfinx_universal.boundaries.curve_samples.SampleHints`) and,
    for each, a bracketed safeguarded Newton method on ``g(t) = c'(t).(c(t) - x) = 0`` in
    ``[t_i - dt, t_i + dt]`` (both neighbouring sample intervals, where ``g`` and ``g'`` come
    from values cached at the samples) from the root of the cubic that interpolates them
    (:func:`~dolfinx_universal.boundaries.curve_samples.hermite_root`); the nearest result
    wins.
    Assumption (dense sampling): the distance to ``x`` is unimodal over any two neighbouring
    sample intervals that hold a local minimum, and the arc between consecutive samples is
    less than 1.5 times their chord; raise ``n_samples`` for curves with features finer than
    ``length / n_samples``.

    Sign: exact and O(1) away from Gamma (see
    :class:`~dolfinx_universal.boundaries.grid.SignGrid`); ``sign((x - pi(x)).N)`` in the grid
    cells that Gamma crosses (exact: the open segment from ``x`` to its closest point does
    not meet Gamma).

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
        return unit(np.column_stack([d[:, 1], -d[:, 0]]))

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
        prev, nxt = neighbours([n])
        return t, p, cKDTree(p), prev, nxt, float(chords(p).max())

    @cached_property
    def _clearance(self) -> tuple[Float, ...]:
        _, p, tree, _, nxt, _ = self._samples
        return window_clearance(tree, p, nxt)

    @cached_property
    def _hints(self) -> SampleHints:
        _, p, tree, prev, nxt, h = self._samples
        return SampleHints(p, tree, prev, nxt, h)

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
        pi, si = candidates(x, tree, ps, prev, nxt, 0.75 * h, self._clearance, start)
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
            t0, bound = hermite_root(glo[br], ghi[br], dga, dgb, lb, hb)
            t0 = np.where(np.isfinite(t0), t0, ts[si][br])
            t[br] = bracketed_newton(
                lambda tt, i: ev(tt, xb[i])[:2], t0, lb, hb, 8 * EPS * T, curvature=bound
            )
        t = np.mod(t, T)
        y = self.point(t)
        best = best_pairs(pi, norm2(y - xs))
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
        if not native(self, ParametricCurve, "closest_point", "normal") or project not in (
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
        if not native(self, ParametricCurve, "closest_point", "normal"):
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
        s = np.concatenate([[0.0], np.cumsum(chords(p))])
        u = np.arange(n) * (s[-1] / max(n, 1))
        return np.mod(np.interp(u, s, np.append(t, self.period)), self.period)

    def loops_normals(self, spacing: float) -> tuple[list[Float], list[Float]]:
        if not native(self, ParametricCurve, "sample", "loops", "normal"):
            return Boundary.loops_normals(self, spacing)
        cached = self.__dict__.get("_last_loops")  # a moving body asks for the same spacing
        if cached is None or cached[0] != spacing:
            n = 1024  # as Boundary.loops; the normals from the parameters, not by projection
            while True:
                t = self._sample_parameters(n)
                p = self.point(t)
                longest = float(chords(p).max())
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
        self.center = vector(center, "center")
        self.period = 2 * np.pi
        th = np.arange(self.n_samples, dtype=np.float64) * (2 * np.pi / self.n_samples)
        rv = call(r, th, th.shape)
        bad = np.flatnonzero(~(np.isfinite(rv) & (rv > 0)))
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"r must be positive and finite: r({th[i]:.6g}) = {rv[i]}")

    def _frame(self, t: Float) -> tuple[Float, Float]:
        u = np.column_stack([np.cos(t), np.sin(t)])
        return u, rot90(u)

    def _c012(self, t: Float) -> tuple[Float, Float, Float]:
        u, v = self._frame(t)  # once for the three (the formulas of point, derivative, ...)
        r, dr, d2r = (call(f, t, t.shape)[:, None] for f in (self.r, self.dr, self.d2r))
        return self.center + r * u, dr * u + r * v, (d2r - r) * u + 2 * dr * v

    def point(self, t: Float) -> Float:
        return self.center + call(self.r, t, t.shape)[:, None] * self._frame(t)[0]

    def derivative(self, t: Float) -> Float:
        u, v = self._frame(t)
        return call(self.dr, t, t.shape)[:, None] * u + call(self.r, t, t.shape)[:, None] * v

    def second_derivative(self, t: Float) -> Float:
        u, v = self._frame(t)
        r, dr, d2r = (call(f, t, t.shape)[:, None] for f in (self.r, self.dr, self.d2r))
        return (d2r - r) * u + 2 * dr * v

    def sign(self, x: npt.ArrayLike) -> Float:
        d = as_points(x) - self.center
        th = np.arctan2(d[:, 1], d[:, 0])
        return np.where(norm2(d) < call(self.r, th, th.shape), -1.0, 1.0)

    project = Boundary.project

    def onto_gamma(self, x: Float) -> tuple[Float, Float]:
        """Points of Gamma near points ``x (n, 2)`` close to it and the outward normals
        there: the point ``c(theta)`` of Gamma on the ray from the pole through ``x`` (one
        evaluation of ``r`` and ``dr``, no search: about a tenth of the cost of a closest
        point). Where the ray meets Gamma at a grazing angle (the point farther from ``x``
        than :data:`~dolfinx_universal.boundaries.base.ONTO_REACH` times its distance from the
        tangent line there), one Newton step along Gamma moves it onto the normal line through
        ``x``; a point still that far gets its closest point."""
        names = ("point", "derivative", "closest_point", "normal", "closest_normal")
        if not native(self, PolarCurve, *names):
            return Boundary.onto_gamma(self, x)
        x = as_points(x)
        d = x - self.center
        t = np.mod(np.arctan2(d[:, 1], d[:, 0]), self.period)
        y, c1 = self._point_derivative(t)
        n = unit(np.column_stack([c1[:, 1], -c1[:, 0]]))  # as _outward()
        bad = np.flatnonzero(~self._near(x, y, n))
        if bad.size:  # Newton on cross(c(t) - x, n) = 0 (its derivative is -|c'(t)|)
            xb, nb = x[bad], n[bad]
            t = t[bad] + cross2(y[bad] - xb, nb) / norm2(c1[bad])
            yb, c1 = self._point_derivative(np.mod(t, self.period))
            nb = unit(np.column_stack([c1[:, 1], -c1[:, 0]]))
            far = np.flatnonzero(~self._near(xb, yb, nb))
            if far.size:
                yb[far], nb[far] = self.closest_normal(xb[far])
            y[bad], n[bad] = yb, nb
        return y, n

    def _point_derivative(self, t: Float) -> tuple[Float, Float]:
        """``c(t)`` and ``c'(t)`` ``(m, 2)`` each, with one evaluation of ``r`` and ``dr``."""
        u, v = self._frame(t)
        r, dr = (call(f, t, t.shape)[:, None] for f in (self.r, self.dr))
        return self.center + r * u, dr * u + r * v  # as point() and derivative()

    def _near(self, x: Float, y: Float, n: Float) -> Bool:
        """Whether the points ``y`` of Gamma (normals ``n``) are within
        :data:`~dolfinx_universal.boundaries.base.ONTO_REACH` times the distance of ``x`` from
        their tangent lines (finite)."""
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
        self.center = vector(center, "center")
        self.a, self.b = positive(a, "a"), positive(b, "b")
        self.angle, self.period = float(angle), 2 * np.pi
        self._cs = np.cos(self.angle), np.sin(self.angle)

    def point(self, t: Float) -> Float:
        p = np.column_stack([self.a * np.cos(t), self.b * np.sin(t)])
        return self.center + rotate(p, *self._cs)

    def derivative(self, t: Float) -> Float:
        return rotate(np.column_stack([-self.a * np.sin(t), self.b * np.cos(t)]), *self._cs)

    def second_derivative(self, t: Float) -> Float:
        return self.center - self.point(t)

    def _local(self, x: npt.ArrayLike) -> Float:
        return rotate(as_points(x) - self.center, self._cs[0], -self._cs[1])

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
        t = bracketed_newton(g, t0, np.zeros(n), np.full(n, np.pi / 2), 4 * EPS)
        t = np.where(p[:, 0] < 0, np.pi - t, t)
        t = np.mod(np.where(p[:, 1] < 0, -t, t), self.period)
        return t, self.point(t)

    def min_radius_of_curvature(self) -> float:
        return min(self.a, self.b) ** 2 / max(self.a, self.b)
