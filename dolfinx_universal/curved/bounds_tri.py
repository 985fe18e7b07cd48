"""Bernstein–Bézier pieces of the Jacobian bounds for triangles (the 2D part of
:func:`~dolfinx_universal.curved.bounds.jacobian_bounds`).

``det J`` of a degree-q triangle map is a polynomial of degree ``2(q - 1)`` on the reference
triangle. Its Bernstein coefficients bound it from below; midpoint subdivision (four
children) of the leaves whose bound is inconclusive tightens the bound (Johnen, Remacle &
Geuzaine 2013). The child coefficients are blossoms of the parent's at the child's vertices
(de Casteljau steps with weights 0, 1/2, 1).
"""

from __future__ import annotations

from collections.abc import Iterator
from functools import lru_cache
from math import factorial

import numpy as np

from dolfinx_universal.core.arrays import Float, Int, lagrange_element, readonly

__all__ = [
    "CHILDREN",
    "MAX_DEPTH",
    "affine_determinant",
    "bernstein_basis",
    "bernstein_indices",
    "control_points",
    "determinant",
    "jacobian_determinant",
    "lattice_blocks",
    "lattice_determinant",
    "subdivision",
]

MAX_DEPTH = 8
"""Subdivision levels of :func:`~dolfinx_universal.curved.bounds.jacobian_bounds` by default
(leaves down to ``4^-8`` of the area)."""

_P0, _P1, _P2 = (0.0, 0.0), (1.0, 0.0), (0.0, 1.0)
_M01, _M12, _M02 = (0.5, 0.0), (0.5, 0.5), (0.0, 0.5)
CHILDREN = np.array([[_P0, _M01, _M02], [_M01, _P1, _M12], [_M02, _M12, _P2], [_M12, _M02, _M01]])
"""Midpoint subdivision of the reference triangle: vertices of the four children ``(4, 3, 2)``."""


@lru_cache(maxsize=16)
def bernstein_indices(order: int) -> Int:
    """Multi-indices ``(a0, a1, a2)``, ``a0 + a1 + a2 = order``, of the Bernstein basis.

    Row ``b`` is the basis polynomial ``B_b = order! / (a0! a1! a2!) l0^a0 l1^a1 l2^a2`` in
    the barycentric coordinates ``(l0, l1, l2) = (1 - X - Y, X, Y)`` of the reference
    triangle; its control point is ``(a1, a2) / order``. Rows run over ``a1`` then ``a2``.

    Returns
    -------
    The indices, ``(nb, 3)`` with ``nb = (order + 1)(order + 2) / 2`` (read-only).
    """
    rows = [(order - i - j, i, j) for i in range(order + 1) for j in range(order + 1 - i)]
    return readonly(np.array(rows, dtype=np.int64))


def control_points(order: int) -> Float:
    """Reference coordinates of the Bernstein control points, ``(nb, 2)``."""
    return bernstein_indices(order)[:, 1:] / max(order, 1)


def bernstein_basis(order: int, points: Float) -> Float:
    """The Bernstein basis of degree ``order`` on the reference triangle at points.

    Parameters
    ----------
    order
        Polynomial degree ``d >= 0``.
    points
        Reference coordinates ``(X, Y)``, ``(p, 2)``.

    Returns
    -------
    ``B[p, b]``, ``(p, nb)``, columns in the order of :func:`bernstein_indices`.
    """
    points = np.asarray(points, dtype=np.float64)
    alpha = bernstein_indices(order)
    lam = np.column_stack([1.0 - points[:, 0] - points[:, 1], points[:, 0], points[:, 1]])
    mult = np.array([factorial(order) / np.prod([factorial(a) for a in r]) for r in alpha])
    return mult * np.prod(lam[:, None, :] ** alpha[None, :, :], axis=2)


def _casteljau_step(order: int, w: Float) -> Float:
    """One de Casteljau step at barycentric point ``w``: degree ``order`` coefficients to
    degree ``order - 1``, ``(nb(order - 1), nb(order))``."""
    index = {tuple(a): k for k, a in enumerate(bernstein_indices(order))}
    lower = bernstein_indices(order - 1)
    step = np.zeros((len(lower), len(index)))
    for r, a in enumerate(lower):
        for i in range(3):
            b = a.copy()
            b[i] += 1
            step[r, index[tuple(b)]] += w[i]
    return step


@lru_cache(maxsize=16)
def subdivision(order: int) -> Float:
    """Midpoint subdivision of Bernstein coefficients of degree ``order``, ``(nb, 8 nb)``.

    ``c @ S`` holds, for child ``k`` of the four, the values of the polynomial at the
    child's control points in columns ``2k nb + (0..nb)`` and its Bernstein coefficients on
    the child in columns ``(2k + 1) nb + (0..nb)``. The coefficients are blossoms at the
    child's vertices (de Casteljau steps with weights 0, 1/2, 1): exact in floating point.
    """
    alpha = bernstein_indices(order)
    nb = len(alpha)
    blocks = []
    for child in CHILDREN:
        w = np.column_stack([1.0 - child.sum(axis=1), child])  # barycentric vertices
        steps = [[_casteljau_step(r, w[i]) for r in range(order, 0, -1)] for i in range(3)]
        coefficients = np.zeros((nb, nb))
        for row, a in enumerate(alpha):
            pts = [i for i in range(3) for _ in range(a[i])]
            op = np.eye(nb)
            for r, i in enumerate(pts):
                op = steps[i][r] @ op  # the blossom is symmetric: any order of the points
            coefficients[row] = op[0]
        values = bernstein_basis(order, control_points(order)) @ coefficients
        blocks += [values.T, coefficients.T]
    return readonly(np.hstack(blocks))


@lru_cache(maxsize=16)
def _lattice_derivatives(degree: int) -> Float:
    """Reference derivatives of the degree-q Lagrange basis at the degree-2(q-1) control
    points, ``(2, nb, ndofs)``."""
    pts = control_points(2 * (degree - 1))
    return readonly(
        np.ascontiguousarray(lagrange_element("triangle", degree).tabulate(1, pts)[1:, :, :, 0])
    )


def determinant(nodes: Float, dphi: Float) -> Float:
    """``det J``, ``(m, p)``, from nodes ``(m, ndofs, 2)`` and derivatives ``(2, p, ndofs)``."""
    p = dphi.shape[1]
    g = nodes.transpose(0, 2, 1) @ np.hstack([dphi[0].T, dphi[1].T])  # (m, 2 (x, y), 2p)
    return g[:, 0, :p] * g[:, 1, p:] - g[:, 1, :p] * g[:, 0, p:]


def jacobian_determinant(nodes: Float, degree: int, points: Float) -> Float:
    """``det J`` of degree-q triangle maps at reference points.

    Parameters
    ----------
    nodes
        Node coordinates of each cell, ``(m, ndofs, 2)``, in DOLFINx's (basix's) node order
        of the GLL-warped Lagrange element of degree ``degree``.
    degree
        Geometry degree ``q >= 1``.
    points
        Reference coordinates, ``(p, 2)``.

    Returns
    -------
    ``det J``, ``(m, p)``.
    """
    dphi = lagrange_element("triangle", degree).tabulate(1, np.asarray(points, dtype=np.float64))[
        1:, :, :, 0
    ]
    return determinant(np.asarray(nodes, dtype=np.float64), dphi)


def lattice_determinant(nodes: Float, degree: int) -> Float:
    """``det J`` at the degree-2(q-1) control points from nodes ``(m, ndofs, 2)``, ``(m, p)``."""
    return determinant(nodes, _lattice_derivatives(degree))


def lattice_blocks(nodes: Float, degree: int) -> Iterator[tuple[int, Float]]:
    """:func:`lattice_determinant` as one block of cells ``(start, det (m, p))``."""
    return iter([(0, lattice_determinant(nodes, degree))])


def affine_determinant(nodes: Float) -> Float:
    """``det J`` of the affine triangle through the vertex nodes ``nodes[:, :3]``, ``(m,)``."""
    p = nodes[:, :3]
    return (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 2, 0] - p[:, 0, 0]) * (
        p[:, 1, 1] - p[:, 0, 1]
    )
