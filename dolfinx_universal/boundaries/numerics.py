"""Numerics shared by the curves and surfaces: argument checks, vectorised norms and
rotations, and a safeguarded Newton method."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from dolfinx_universal.core.arrays import Float, Int

__all__ = [
    "EPS",
    "ArrayFn",
    "best_pairs",
    "bracketed_newton",
    "call",
    "distances",
    "normd",
    "plane_basis",
    "rotate",
    "rotation_matrix",
    "split",
    "unit",
    "vector",
]


ArrayFn = Callable[[Float], Float]

EPS = float(np.finfo(np.float64).eps)


def vector(v: npt.ArrayLike, name: str, dim: int = 2) -> Float:
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


def distances(distance: float | npt.ArrayLike, n: int) -> Float:
    """``distance`` (one, or one per point) as ``n`` finite numbers ``>= 0``."""
    if np.ndim(distance) == 0:
        return np.full(n, _distance(float(distance)))  # type: ignore[arg-type]
    d = np.asarray(distance, dtype=np.float64)
    if d.shape != (n,):
        raise ValueError(f"distance must be a number or one per point ({n},), got {d.shape}")
    if not (np.isfinite(d) & (d >= 0)).all():
        raise ValueError("distance must be finite numbers >= 0")
    return d


def call(fn: ArrayFn, arg: Float, shape: tuple[int, ...], name: str = "") -> Float:
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


def normd(v: Float) -> Float:
    """Euclidean norms of the rows of ``v (..., d)``: for ``d = 2`` those of
    :func:`~dolfinx_universal.core.arrays.norm2` (the same arithmetic)."""
    squares = v[..., 0] ** 2
    for k in range(1, v.shape[-1]):
        squares = squares + v[..., k] ** 2
    return np.sqrt(squares)


def unit(v: Float) -> Float:
    """The rows of ``v (n, d)`` divided by their norms."""
    return v / normd(v)[:, None]


def plane_basis(normal: Float) -> Float:
    """Orthonormal tangent bases ``(n, 2, 3)`` of the planes of unit normals ``(n, 3)``.

    ``t1 = unit(e_k x N)`` with ``e_k`` the coordinate axis least aligned with ``N``, and
    ``t2 = N x t1``, so that ``(t1, t2, N)`` is right-handed (``t1 x t2 = N``). The choice
    jumps where the least aligned axis changes (no continuous choice exists on a sphere).
    """
    k = np.argmin(np.abs(normal), axis=1)
    e = np.zeros_like(normal)
    e[np.arange(len(normal)), k] = 1.0
    t1 = np.cross(e, normal)
    t1 /= normd(t1)[:, None]
    t2 = np.cross(normal, t1)
    return np.stack([t1, t2], axis=1)


def rotation_matrix(rotation: object, name: str = "rotation") -> Float:
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
        and np.shape(rotation[1]) == ()
        and np.size(rotation[0]) == 3
    ):
        axis = vector(rotation[0], f"{name} axis", 3)
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


def rotate(v: Float, c: float, s: float) -> Float:
    """Planar vectors ``v (..., 2)`` rotated by the angle of cosine ``c`` and sine ``s``."""
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


def split(n: int, weights: Sequence[float]) -> list[int]:
    """``n`` split proportionally to ``weights`` (largest remainders)."""
    w = np.asarray(weights, dtype=np.float64)
    q = n * w / w.sum()
    k = np.floor(q).astype(int)
    k[np.argsort(k - q)[: n - k.sum()]] += 1
    return k.tolist()


def best_pairs(pidx: Int, dist: Float) -> Int:
    """Index of the pair with the smallest ``dist`` for each point ``0, 1, ...`` of ``pidx``."""
    if len(pidx) == pidx.max(initial=-1) + 1:  # one pair per point
        return np.argsort(pidx, kind="stable")
    order = np.lexsort((dist, pidx))
    p = pidx[order]
    first = np.ones(len(p), dtype=bool)
    first[1:] = p[1:] != p[:-1]
    return order[first]


def bracketed_newton(
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
