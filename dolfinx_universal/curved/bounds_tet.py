"""Bernstein–Bézier pieces of the Jacobian bounds for tetrahedra (the 3D part of
:func:`~dolfinx_universal.curved.bounds.jacobian_bounds`).

``det J`` of a degree-q tetrahedron map is a polynomial of degree ``3(q - 1)`` on the
reference tetrahedron. Its Bernstein coefficients bound it from below; red refinement (eight
children: four corner tetrahedra and four around the diagonal ``M02 - M13`` of the inner
octahedron) of the leaves whose bound is inconclusive tightens the bound (Johnen, Remacle &
Geuzaine 2013). The child coefficients are blossoms of the parent's at the child's vertices
(de Casteljau steps with weights 0, 1/2, 1).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
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
    "derivative_factors",
    "determinant",
    "lattice_blocks",
    "lattice_determinant",
    "subdivision",
]


MAX_DEPTH = 6
"""Subdivision levels of :func:`~dolfinx_universal.curved.bounds.jacobian_bounds` by default
(leaves down to ``8^-6`` of the volume)."""

_P = np.eye(4)[:, 1:]  # reference vertices P0..P3
_M = {(i, j): 0.5 * (_P[i] + _P[j]) for i in range(4) for j in range(i + 1, 4)}
CHILDREN = np.array(
    [
        [_P[0], _M[0, 1], _M[0, 2], _M[0, 3]],
        [_M[0, 1], _P[1], _M[1, 2], _M[1, 3]],
        [_M[0, 2], _M[1, 2], _P[2], _M[2, 3]],
        [_M[0, 3], _M[1, 3], _M[2, 3], _P[3]],
        [_M[0, 2], _M[1, 3], _M[0, 1], _M[0, 3]],
        [_M[0, 2], _M[1, 3], _M[0, 3], _M[2, 3]],
        [_M[0, 2], _M[1, 3], _M[2, 3], _M[1, 2]],
        [_M[0, 2], _M[1, 3], _M[1, 2], _M[0, 1]],
    ]
)
"""Red refinement of the reference tetrahedron: vertices of the eight children ``(8, 4, 3)``,
each of volume 1/48."""


@lru_cache(maxsize=16)
def bernstein_indices(order: int) -> Int:
    """Multi-indices ``(a0, a1, a2, a3)``, sum ``order``, of the Bernstein basis.

    Row ``b`` is ``B_b = order! / (a0! a1! a2! a3!) l0^a0 l1^a1 l2^a2 l3^a3`` in the
    barycentric coordinates ``(1 - X - Y - Z, X, Y, Z)``; its control point is
    ``(a1, a2, a3) / order``.

    Returns
    -------
    The indices, ``(nb, 4)`` with ``nb = (order + 1)(order + 2)(order + 3) / 6`` (read-only).
    """
    rows = [
        (order - i - j - k, i, j, k)
        for i in range(order + 1)
        for j in range(order + 1 - i)
        for k in range(order + 1 - i - j)
    ]
    return readonly(np.array(rows, dtype=np.int64).reshape(-1, 4))


def control_points(order: int) -> Float:
    """Reference coordinates of the Bernstein control points, ``(nb, 3)``."""
    return bernstein_indices(order)[:, 1:] / max(order, 1)


def bernstein_basis(order: int, points: Float) -> Float:
    """The Bernstein basis of degree ``order`` on the reference tetrahedron at points.

    Parameters
    ----------
    order
        Polynomial degree ``d >= 0``.
    points
        Reference coordinates ``(p, 3)``.

    Returns
    -------
    ``B[p, b]``, ``(p, nb)``, columns in the order of :func:`bernstein_indices`.
    """
    points = np.asarray(points, dtype=np.float64)
    alpha = bernstein_indices(order)
    lam = np.column_stack([1.0 - points.sum(axis=1), points])
    mult = np.array([factorial(order) / np.prod([factorial(a) for a in r]) for r in alpha])
    return mult * np.prod(lam[:, None, :] ** alpha[None, :, :], axis=2)


@lru_cache(maxsize=16)
def _raise_index(order: int) -> Int:
    """``idx[i, r]``: the row of ``a + e_i`` among the degree-``order`` indices for row ``r``
    of the degree ``order - 1`` indices, ``(4, nb(order - 1))``."""
    index = {tuple(a): k for k, a in enumerate(bernstein_indices(order).tolist())}
    lower = bernstein_indices(order - 1)
    return np.array(
        [[index[tuple(a + np.eye(4, dtype=np.int64)[i])] for a in lower] for i in range(4)]
    )


def _child_operator(order: int, w: Float) -> Float:
    """Bernstein coefficients on the child with barycentric vertices ``w (4, 4)`` as a linear
    map of the parent's: ``(nb, nb)``.

    The coefficient of index ``a`` is the blossom at ``a0`` copies of ``w0``, ..., ``a3`` of
    ``w3``: de Casteljau steps, shared between indices through the prefixes
    ``(a0), (a0, a1), (a0, a1, a2)``; the last ``a3`` steps at ``w3`` evaluate a polynomial
    of degree ``a3`` at ``w3``.
    """
    nb = len(bernstein_indices(order))

    def step(t: Float, r: int, point: Float) -> Float:  # degree r -> r - 1
        idx = _raise_index(r)
        return sum(point[i] * t[idx[i]] for i in range(4))

    out = np.zeros((nb, nb))
    row = {tuple(a): k for k, a in enumerate(bernstein_indices(order).tolist())}
    t0 = np.eye(nb)
    for a0 in range(order + 1):
        t1 = t0
        for a1 in range(order + 1 - a0):
            t2 = t1
            for a2 in range(order + 1 - a0 - a1):
                a3 = order - a0 - a1 - a2
                basis = bernstein_basis(a3, w[3][None, 1:])[0]
                out[row[(a0, a1, a2, a3)]] = basis @ t2
                if a3 > 0:
                    t2 = step(t2, a3, w[2])
            rest = order - a0 - a1
            if rest > 0:
                t1 = step(t1, rest, w[1])
        rest = order - a0
        if rest > 0:
            t0 = step(t0, rest, w[0])
    return out


@lru_cache(maxsize=8)
def subdivision(order: int) -> Float:
    """Red subdivision of Bernstein coefficients of degree ``order``, ``(nb, 16 nb)``.

    ``c @ S`` holds, for child ``k`` of :data:`CHILDREN`, the values of the polynomial at the
    child's control points in columns ``2k nb + (0..nb)`` and its Bernstein coefficients on
    the child in columns ``(2k + 1) nb + (0..nb)``.
    """
    nb = len(bernstein_indices(order))
    blocks = []
    for child in CHILDREN:
        w = np.column_stack([1.0 - child.sum(axis=1), child])
        coefficients = _child_operator(order, w) if order else np.ones((1, 1))
        values = bernstein_basis(order, control_points(order)) @ coefficients
        blocks += [values.T, coefficients.T]
    assert blocks[0].shape == (nb, nb)
    return readonly(np.hstack(blocks))


@lru_cache(maxsize=16)
def derivative_factors(degree: int) -> tuple[Float, Float]:
    """The reference derivatives of the degree-q Lagrange basis at the degree-3(q-1) control
    points, as a product of two smaller matrices.

    The derivatives are polynomials of degree ``q - 1``: their Bernstein coefficients
    ``D``, ``(ndofs, 3 nb)`` (columns: direction, then coefficient), and the degree-
    ``(q - 1)`` Bernstein basis at the ``p`` control points ``B``, ``(nb, p)``, give the
    derivatives there as ``D`` then ``B``: ``nb`` (4, 10, 20 at q = 2, 3, 4) is much
    smaller than ``p`` (20, 84, 220), so two products cost about 60 % of one at q = 3 and
    55 % at q = 4.
    """
    low = degree - 1
    pts = control_points(low)
    values = lagrange_element("tetrahedron", degree).tabulate(1, pts)[1:, :, :, 0]  # (3, nb, n)
    nb, n = values.shape[1:]
    coef = np.linalg.solve(bernstein_basis(low, pts), values.transpose(1, 0, 2).reshape(nb, -1))
    d = coef.reshape(nb, 3, n).transpose(2, 1, 0).reshape(n, 3 * nb)
    b = bernstein_basis(low, control_points(3 * low)).T
    return readonly(np.ascontiguousarray(d)), readonly(np.ascontiguousarray(b))


_CHUNK = 512
"""Cells per block of :func:`determinant` and :func:`lattice_determinant` (their nine
``(cells, p)`` factors stay in cache), half as many beyond 35 points (q >= 3: measured 10 %
faster at q = 3, the same at q = 4; at q = 2 the full block is the fastest)."""


def _cofactor(j: Float) -> Float:
    """``det`` of the Jacobians ``j[i, k]`` (each ``(c, p)``: ``d x_i / d X_k``), ``(c, p)``."""
    a = j[1, 1] * j[2, 2]
    a -= j[1, 2] * j[2, 1]
    a *= j[0, 0]
    b = j[1, 0] * j[2, 2]
    b -= j[1, 2] * j[2, 0]
    b *= j[0, 1]
    a -= b
    b = j[1, 0] * j[2, 1]
    b -= j[1, 1] * j[2, 0]
    b *= j[0, 2]
    a += b
    return a


def _blocks(
    nodes: Float, d: Float, p: int, entries: Callable[[Float, int], Float]
) -> Iterator[tuple[int, Float]]:
    """``det J`` in blocks of :data:`_CHUNK` cells, ``(start, det (c, p))``: the product of
    each block's coordinates ``(3 c, ndofs)`` with ``d`` is turned into the Jacobian entries
    ``j[i, k]`` (each ``(c, p)``) by ``entries(product, c)``, then expanded by cofactors."""
    m, n, _ = nodes.shape
    chunk = _CHUNK if p <= 35 else _CHUNK // 2
    for s in range(0, m, chunk):
        block = nodes[s : s + chunk]
        c = len(block)
        yield s, _cofactor(entries(block.transpose(2, 0, 1).reshape(3 * c, n) @ d, c))


def _gathered(blocks: Iterator[tuple[int, Float]], m: int, p: int) -> Float:
    """The blocks of :func:`_blocks` as one array ``(m, p)``."""
    out = np.empty((m, p))
    for s, det in blocks:
        out[s : s + len(det)] = det
    return out


def determinant(nodes: Float, dphi: Float) -> Float:
    """``det J``, ``(m, p)``, from nodes ``(m, ndofs, 3)`` and derivatives ``(3, p, ndofs)``.

    Blocks of :data:`_CHUNK` cells: one matrix product gives the Jacobian entries at the
    ``p`` points, the cofactor expansion runs on its rows of ``p`` contiguous values.
    """
    n, p = nodes.shape[1], dphi.shape[1]
    d = np.ascontiguousarray(dphi.transpose(2, 0, 1).reshape(n, 3 * p))  # (ndofs, (k, p))

    def entries(g: Float, c: int) -> Float:
        return g.reshape(3, c, 3, p).transpose(0, 2, 1, 3)

    return _gathered(_blocks(nodes, d, p, entries), len(nodes), p)


def lattice_blocks(nodes: Float, degree: int) -> Iterator[tuple[int, Float]]:
    """``det J`` at the degree-3(q-1) control points from nodes ``(m, ndofs, 3)``, in
    blocks of cells ``(start, det (c, p))``: :func:`determinant` with the derivatives at
    those points, the Jacobian entries by the two products of :func:`derivative_factors`
    (the same values to rounding, in about 70 % of the time at q = 3 on curved
    tetrahedra). A caller that reduces each block while it is in cache saves a pass over
    the whole ``(m, p)`` array (:func:`~dolfinx_universal.curved.bounds.jacobian_bounds`)."""
    d, b = derivative_factors(degree)
    nb, p = b.shape

    def entries(g: Float, c: int) -> Float:
        g = g.reshape(3, c, 3, nb).transpose(0, 2, 1, 3).reshape(9 * c, nb)
        return (g @ b).reshape(3, 3, c, p)

    return _blocks(nodes, d, p, entries)


def lattice_determinant(nodes: Float, degree: int) -> Float:
    """``det J`` at the degree-3(q-1) control points, ``(m, p)`` (:func:`lattice_blocks`)."""
    return _gathered(
        lattice_blocks(nodes, degree), len(nodes), derivative_factors(degree)[1].shape[1]
    )


def affine_determinant(nodes: Float) -> Float:
    """``det J`` of the affine tetrahedron through the vertex nodes ``nodes[:, :4]``, ``(m,)``."""
    p = nodes[:, :4]
    a, b, c = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
    return (
        a[:, 0] * (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1])
        - b[:, 0] * (a[:, 1] * c[:, 2] - a[:, 2] * c[:, 1])
        + c[:, 0] * (a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1])
    )
