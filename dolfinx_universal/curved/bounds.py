"""Proven bounds of the Jacobian determinant of curved triangles and tetrahedra by Bernstein–Bézier
subdivision; the per-cell-type pieces are in :mod:`.bounds_tri` and :mod:`.bounds_tet`."""

from __future__ import annotations

from collections.abc import Iterator
from functools import lru_cache
from types import ModuleType

import numpy as np
import numpy.typing as npt
from scipy.linalg import lu_factor, lu_solve

from dolfinx_universal.cells.kit import cell_kernels
from dolfinx_universal.core.arrays import Float, readonly
from dolfinx_universal.curved import bounds_tet, bounds_tri

__all__ = [
    "MAX_DEGREE",
    "bernstein_coefficients",
    "check_degree",
    "jacobian_bounds",
]


_PIECES: dict[int, ModuleType] = {2: bounds_tri, 3: bounds_tet}
"""The Bernstein–Bézier pieces per topological dimension (the same names in both modules:
``bernstein_basis``, ``control_points``, ``subdivision``, ``CHILDREN``, ``MAX_DEPTH``,
``lattice_blocks``, ``lattice_determinant``, ``affine_determinant``)."""

MAX_DEGREE = {2: 7, 3: 5}
"""The highest geometry degree ``q`` per topological dimension whose validity proof is
accurate. The Bernstein coefficients of ``det J`` (degree ``tdim (q - 1)``) come from its
values at the control points (``_ToBernstein``); the condition of that change of basis
grows about sevenfold per degree for triangles and twentyfold for tetrahedra. Measured (a
random polynomial with coefficients in [0.5, 1.5], its coefficients recovered from its
values, on five OpenBLAS core types): at most 1.6e-11 at q = 7 for triangles and 2.8e-11 at
q = 5 for tetrahedra. Beyond the limits the error grows fast (triangles q = 8 to 11: 1.1e-10,
6.6e-10, 4.3e-9, 3.8e-8; tetrahedra q = 6 to 8: 5.7e-10, 7.5e-9, 1.6e-7), and tetrahedra of
degree 6 to 8 cost 3 to 50 s and up to 0.5 GB to set up the subdivision operators."""


_INVERSE_UP_TO = 6e3
"""Largest row sum of the inverse collocation matrix for which ``_ToBernstein``
multiplies by the inverse: triangles up to q = 5 (row sum 1083; 7508 at q = 6), tetrahedra
up to q = 4 (4868; 98330 at q = 5). A product with the inverse sums terms up to that size
into values of size 1: measured 1.3e-12 (triangles, q = 5) and 1.7e-11 (tetrahedra, q = 4)
at most. Beyond it the explicit inverse lost up to 6e-9 (tetrahedra, q = 5, depending on the
CPU kernel), and the LU factors solve instead: 3e-11 at most, the condition of the change of
basis times the rounding of the values, at 1.6 to 2 times the cost of the product."""


class _ToBernstein:
    """Values of polynomials at the Bernstein control points -> their Bernstein coefficients.

    ``coefficients = _ToBernstein(B)(values)`` solves ``B c = v`` for every row of
    ``values (m, nb)``, with ``B (nb, nb)`` the Bernstein basis at the control points: by
    the explicit inverse where its rows sum to at most ``_INVERSE_UP_TO`` (a matrix
    product, the fastest), else by the LU factors (backward stable: the error is then the
    change of basis's own condition times the rounding of the values).
    """

    def __init__(self, collocation: Float) -> None:
        inverse = np.linalg.inv(collocation)
        small = np.abs(inverse).sum(axis=1).max() <= _INVERSE_UP_TO
        self.inverse_t = readonly(np.ascontiguousarray(inverse.T)) if small else None
        self.lu = None if small else lu_factor(collocation)

    def __call__(self, values: Float) -> Float:
        """The coefficients ``(m, nb)`` of the rows of ``values (m, nb)``."""
        if self.inverse_t is not None:
            return values @ self.inverse_t
        # (nb, m) Fortran-ordered in and out: its transpose is the C-ordered (m, nb)
        return lu_solve(self.lu, values.T, check_finite=False).T


@lru_cache(maxsize=16)
def _to_bernstein(tdim: int, order: int) -> _ToBernstein:
    """The ``_ToBernstein`` of degree ``order`` on the reference triangle (``tdim = 2``)
    or tetrahedron (``tdim = 3``), at the control points of its ``bernstein_basis``."""
    pieces = _PIECES[tdim]
    return _ToBernstein(pieces.bernstein_basis(order, pieces.control_points(order)))


def check_degree(degree: float, tdim: int) -> int:
    """The geometry degree as an ``int``, if it is an integer from 1 to ``MAX_DEGREE[tdim]``.

    Raises
    ------
    ValueError
        Otherwise, naming the reason (the rounding of the validity proof above the limit).
    """
    if isinstance(degree, bool) or int(degree) != degree or degree < 1:
        raise ValueError(f"geometry degree must be an integer >= 1, got {degree}")
    top = MAX_DEGREE[tdim]
    if degree > top:
        raise ValueError(
            f"geometry degree {int(degree)} is above {top}, the highest for "
            f"{cell_kernels(tdim).plural}: the "
            f"proof that curved cells are valid (Bernstein coefficients of det J, of degree "
            f"{tdim}(q - 1)) is accurate to about 1e-11 up to it and loses accuracy to "
            f"rounding fast beyond it"
        )
    return int(degree)


def bernstein_coefficients(nodes: Float, degree: int) -> Float:
    """Bernstein coefficients of ``det J`` (a polynomial of degree ``d = tdim (q-1)``).

    Exact up to rounding: ``det J`` is evaluated at the ``nb`` control points and the
    collocation matrix inverted. ``det J(X) = sum_b c[:, b] B_b(X)`` with ``B`` the
    ``bernstein_basis`` of degree ``d`` of :mod:`.bounds_tri` or :mod:`.bounds_tet`.

    Parameters
    ----------
    nodes
        Node coordinates of each cell, ``(m, ndofs, 2)`` (triangles) or ``(m, ndofs, 3)``
        (tetrahedra).
    degree
        Geometry degree ``q >= 1``.

    Returns
    -------
    The coefficients ``c``, ``(m, nb)`` with ``nb`` the dimension of the degree-``d``
    polynomials (``(d + 1)(d + 2) / 2`` on triangles).
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    tdim = _cell_dimension(nodes)
    det = _PIECES[tdim].lattice_determinant(nodes, degree)
    return _to_bernstein(tdim, tdim * (degree - 1))(det)


def _cell_dimension(nodes: Float) -> int:
    """The dimension of the cells whose nodes are ``nodes (m, ndofs, gdim)`` (an argument
    of the entry points): 3 for tetrahedra (three coordinates), else 2 (triangles)."""
    return 3 if nodes.ndim == 3 and nodes.shape[2] == 3 else 2


def _first_level(
    blocks: Iterator[tuple[int, Float]], det0: Float, to_bernstein: _ToBernstein, nb: int
) -> tuple[npt.NDArray[np.bool_], Float, Float]:
    """The ratios ``det J / det J_affine`` at the control points, block by block of cells
    (``(start, det)``, each reduced while it is in cache): the cells whose ratio is not
    defined (``det J_affine = 0`` or a value not finite; their ratios count as 1), the
    smallest ratio of each cell and its Bernstein coefficients ``(m, nb)``."""
    m = len(det0)
    bad, upper, coef = np.empty(m, dtype=bool), np.empty(m), np.empty((m, nb))
    for s, det in blocks:
        rows = slice(s, s + len(det))
        d0 = det0[rows]
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = det / d0[:, None]
        undefined = (d0 == 0) | ~np.isfinite(ratio).all(axis=1)
        ratio[undefined] = 1.0
        bad[rows], upper[rows], coef[rows] = undefined, ratio.min(axis=1), to_bernstein(ratio)
    return bad, upper, coef


def jacobian_bounds(
    nodes: Float,
    degree: int,
    *,
    threshold: float = 0.0,
    max_depth: int | None = None,
    rtol: float = 0.05,
) -> tuple[Float, Float]:
    """Proven lower bound and an attained upper bound of ``min det J / det J_affine`` per cell.

    ``det J_affine`` is the determinant of the affine cell through the vertex nodes.
    ``det J`` is written in the Bernstein basis of degree ``tdim (q-1)`` on the reference
    triangle or tetrahedron (or on sub-cells of it): the smallest coefficient bounds ``det J``
    from below there, and values of ``det J`` at points (the control points, corners
    included) bound its minimum from above (Johnen, Remacle & Geuzaine 2013). Sub-cells
    (leaves) are split at their edge midpoints into four triangles or eight tetrahedra (red
    refinement), all cells at once, while

    * the decision is open: ``lower <= threshold < upper``: every leaf whose lower bound is
      at or below ``threshold`` is split; or
    * the bounds are loose: a leaf whose lower bound is below ``upper - tol`` is split, with
      ``tol = rtol * max(|upper|, 0.01)``, so that the reported lower bound is the minimum
      to about ``rtol`` relatively (absolutely ``rtol / 100`` where the minimum is near 0).

    Leaves that fulfil neither are kept with their bound. At ``max_depth`` splits the
    remaining leaves keep theirs: an undecided cell then keeps ``lower <= threshold``, which
    callers treat as failing (conservative). The work is a few small matrix products per
    level on the undecided leaves only; ``rtol=np.inf`` decides ``threshold`` and nothing more.

    The bounds are exact up to rounding, which grows with the degree (:data:`MAX_DEGREE`:
    about ``1e-13`` relative to the largest ratio up to q = 5 for triangles and q = 3 for
    tetrahedra, about ``1e-11`` above them, up to the highest degrees allowed).
    Cells whose vertices are collinear or coplanar (``det J_affine = 0``) or whose nodes are
    not finite get ``-inf`` for both.

    Parameters
    ----------
    nodes
        Node coordinates of each cell, ``(m, ndofs, 2)`` for triangles, ``(m, ndofs, 3)`` for
        tetrahedra, in DOLFINx's node order of the GLL-warped Lagrange element of degree
        ``degree``.
    degree
        Geometry degree ``q >= 1`` (``q = 1``: ``det J`` is constant, both bounds are 1), at
        most :data:`MAX_DEGREE` (a ``ValueError`` above it).
    threshold
        The ratio to decide (default 0: inversion).
    max_depth
        Largest number of subdivision levels (leaves down to ``4^-max_depth`` of the area,
        ``8^-max_depth`` of the volume); default 8 for triangles, 6 for tetrahedra.
    rtol
        Relative gap between the bounds at which a cell is not refined further for
        tightness (the decision at ``threshold`` is refined regardless; ``np.inf``: never).

    Returns
    -------
    lower
        Proven lower bound of ``min det J / det J_affine`` over each cell, ``(m,)``.
    upper
        The smallest ratio attained at an evaluated point of each cell, ``(m,)``:
        ``lower <= min <= upper``.
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    m = len(nodes)
    tdim = _cell_dimension(nodes)
    pieces = _PIECES[tdim]
    degree = check_degree(degree, tdim)
    order = tdim * (degree - 1)
    det0 = pieces.affine_determinant(nodes)
    blocks = pieces.lattice_blocks(nodes, degree)
    split, nchildren = pieces.subdivision(order), len(pieces.CHILDREN)
    max_depth = pieces.MAX_DEPTH if max_depth is None else max_depth
    nb = split.shape[0]
    bad, upper, coef = _first_level(blocks, det0, _to_bernstein(tdim, order), nb)
    lower = np.full(m, np.inf)
    cell = np.arange(m)  # the cell of each leaf
    for depth in range(max_depth + 1):
        low = coef.min(axis=1)
        up = upper[cell]
        with np.errstate(invalid="ignore"):  # rtol = inf
            loose = low < up - rtol * np.maximum(np.abs(up), 0.01)
        refine = loose | ((low <= threshold) & (threshold < up))
        np.minimum.at(lower, cell[~refine], low[~refine])
        if depth == max_depth or not refine.any():
            np.minimum.at(lower, cell[refine], low[refine])
            break
        cell, coef = cell[refine], coef[refine]
        children = (coef @ split).reshape(
            len(cell), nchildren, 2, nb
        )  # (leaves, child, value/coef, nb)
        np.minimum.at(upper, cell, children[:, :, 0].min(axis=(1, 2)))
        coef = children[:, :, 1].reshape(-1, nb)
        cell = np.repeat(cell, nchildren)
    lower = np.minimum(lower, upper)  # the corner coefficients are values: only rounding
    lower[bad] = upper[bad] = -np.inf
    return lower, upper
