"""Proven Jacobian bounds of curved triangles: Bernstein coefficients and subdivision."""

import time

import numpy as np
import pytest

from dolfinx_universal.core.arrays import lagrange_element
from dolfinx_universal.curved import bounds_tet as _tet
from dolfinx_universal.curved.bounds import (
    MAX_DEGREE,
    _to_bernstein,
    bernstein_coefficients,
    check_degree,
    jacobian_bounds,
)
from dolfinx_universal.curved.bounds_tri import (
    bernstein_basis,
    bernstein_indices,
    jacobian_determinant,
    subdivision,
)
from dolfinx_universal.curved.maps import jacobian_ratio
from dolfinx_universal.curved.maps_tet import reference_nodes as tet_reference_nodes_lam
from dolfinx_universal.curved.maps_tri import reference_nodes

TRI = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
CHILDREN = np.array(
    [
        [[0.0, 0.0], [0.5, 0.0], [0.0, 0.5]],
        [[0.5, 0.0], [1.0, 0.0], [0.5, 0.5]],
        [[0.0, 0.5], [0.5, 0.5], [0.0, 1.0]],
        [[0.5, 0.5], [0.0, 0.5], [0.5, 0.0]],
    ]
)

# Cells whose det J is negative only between the points of the 4q lattice: q = 2 dips near
# (0.28, 0) on edge 2, between the lattice points 1/4 and 3/8; q = 3 near (0.46, 0.54) on
# edge 0, between 5/12 and 1/2 (moves of edge nodes, as a boundary edge curving inwards).
FOLDS = {2: {3: (0.88, 1.84), 5: (0.32, 1.68)}, 3: {3: (-0.32, 0.32), 4: (-0.036, 0.214)}}


def lattice(n: int) -> np.ndarray:
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    return np.column_stack([i[keep], j[keep]]) / n


def affine_det(nodes: np.ndarray) -> np.ndarray:
    a, b = nodes[:, 1] - nodes[:, 0], nodes[:, 2] - nodes[:, 0]
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def sampled_min(nodes: np.ndarray, degree: int, n: int) -> np.ndarray:
    """Smallest ``det J / det J_affine`` on the lattice of n subdivisions (the former check
    used ``n = 4q``)."""
    det = jacobian_determinant(nodes, degree, lattice(n))
    return (det / affine_det(nodes)[:, None]).min(axis=1)


def random_cells(degree: int, m: int, rng: np.random.Generator, amp: float) -> np.ndarray:
    nodes = reference_nodes(degree) @ TRI
    return nodes + amp * rng.standard_normal((m,) + nodes.shape)


def folded(degree: int, scale: float = 1.0) -> np.ndarray:
    nodes = reference_nodes(degree) @ TRI
    for i, move in FOLDS[degree].items():
        nodes[i] += scale * np.array(move)
    return nodes[None]


def random_points(rng: np.random.Generator, n: int) -> np.ndarray:
    p = rng.random((2 * n, 2))
    return p[p.sum(axis=1) <= 1.0][:n]


@pytest.mark.parametrize("degree", [1, 2, 3, 4, 5])
def test_bernstein_coefficients_reproduce_det(degree):
    rng = np.random.default_rng(degree)
    nodes = random_cells(degree, 40, rng, 0.08)
    pts = random_points(rng, 100)
    c = bernstein_coefficients(nodes, degree)
    order = 2 * (degree - 1)
    assert c.shape == (40, (order + 1) * (order + 2) // 2) == (40, len(bernstein_indices(order)))
    exact = jacobian_determinant(nodes, degree, pts)
    # A change of basis with a collocation matrix of condition <= 515 (order 8): rounding of
    # at most about 515 eps = 1e-13 relative, here and at the corners.
    assert np.abs(c @ bernstein_basis(order, pts).T - exact).max() < 1e-12 * np.abs(exact).max()
    # The corner coefficients are the values at the corners.
    alpha = bernstein_indices(order)
    corners = [int(np.flatnonzero((alpha == order * e).all(1))[0]) for e in np.eye(3, dtype=int)]
    assert np.allclose(c[:, corners], jacobian_determinant(nodes, degree, TRI), atol=1e-12)


@pytest.mark.parametrize("order", [0, 2, 4, 6, 8])
def test_subdivision_is_exact(order):
    """The child coefficients reproduce the parent polynomial on each child; the operators are
    convex combinations (nonnegative, partition of unity)."""
    rng = np.random.default_rng(order)
    nb = len(bernstein_indices(order))
    c = rng.standard_normal((3, nb))
    split = subdivision(order).reshape(nb, 4, 2, nb)
    ref = random_points(rng, 30)  # in the child's reference coordinates
    lam = np.column_stack([1.0 - ref.sum(axis=1), ref])
    for k, child in enumerate(CHILDREN):
        parent_pts = lam @ child
        want = c @ bernstein_basis(order, parent_pts).T
        got = (c @ split[:, k, 1]) @ bernstein_basis(order, ref).T
        # convex combinations of standard normal coefficients: rounding of about 1e-15
        assert np.abs(got - want).max() < 1e-12
        ctrl = bernstein_indices(order) / max(order, 1) @ child
        assert np.allclose(c @ split[:, k, 0], c @ bernstein_basis(order, ctrl).T, atol=1e-12)
    assert split[:, :, 1].min() >= 0.0
    assert np.abs(split[:, :, 1].sum(axis=0) - 1.0).max() == 0.0


@pytest.mark.parametrize("degree", [2, 3, 4])
def test_bounds_bracket_the_minimum(degree):
    rng = np.random.default_rng(10 + degree)
    nodes = np.concatenate([random_cells(degree, 100, rng, a) for a in (0.02, 0.06, 0.15)])
    lower, upper = jacobian_bounds(nodes, degree)
    dense = sampled_min(nodes, degree, 200)
    # (1e-12: slack for the bounds' rounding, about 1e-13 relative to O(1) ratios)
    assert (lower <= dense + 1e-12).all()
    assert (lower <= upper).all()
    assert (upper - lower <= 0.05 * np.maximum(np.abs(upper), 0.01) + 1e-12).all()  # rtol
    assert (lower > 0).any() and (upper <= 0).any()  # both kinds of cell are in the sample
    # With few levels every evaluated point lies on the lattice of order * 2^depth
    # subdivisions: its minimum is bracketed exactly.
    lower, upper = jacobian_bounds(nodes, degree, max_depth=3)
    dense = sampled_min(nodes, degree, 2 * (degree - 1) * 2**3)
    assert (lower <= dense + 1e-12).all() and (dense <= upper + 1e-12).all()


@pytest.mark.parametrize("degree", [2, 3])
def test_inversion_between_lattice_points_is_caught(degree):
    nodes = folded(degree)
    assert sampled_min(nodes, degree, 4 * degree)[0] > 0.01  # the 4q lattice says valid
    dense = sampled_min(nodes, degree, 400)[0]
    assert dense < -0.005  # but det J is negative in between
    lower, upper = jacobian_bounds(nodes, degree)
    assert lower[0] <= dense <= upper[0] + 1e-3
    assert upper[0] < 0  # proven inverted: a negative value was found
    assert jacobian_ratio(nodes, degree)[0] < 0


@pytest.mark.parametrize("degree", [2, 3])
def test_nearly_degenerate_cell_is_proven_valid(degree):
    nodes = folded(degree, 0.99)
    dense = sampled_min(nodes, degree, 400)[0]
    assert 0 < dense < 0.02
    assert jacobian_bounds(nodes, degree, max_depth=0)[0][0] < 0  # the coefficients alone fail
    lower, upper = jacobian_bounds(nodes, degree)
    assert 0 < lower[0] <= dense <= upper[0] + 1e-3
    assert upper[0] - lower[0] <= 0.05 * upper[0]
    assert jacobian_ratio(nodes, degree)[0] > 0


def test_threshold_and_rtol_semantics():
    nodes = folded(3, 0.9)
    dense = sampled_min(nodes, 3, 400)[0]
    # rtol=inf only decides the threshold: valid at 0, not above the minimum.
    lower, upper = jacobian_bounds(nodes, 3, rtol=np.inf)
    assert 0 < lower[0] <= dense
    lower, upper = jacobian_bounds(nodes, 3, threshold=0.9 * dense, rtol=np.inf)
    assert 0.9 * dense < lower[0] <= dense
    lower, upper = jacobian_bounds(nodes, 3, threshold=1.1 * dense, rtol=np.inf)
    assert upper[0] <= 1.1 * dense
    # max_depth reached while undecided: the bound stays at or below the threshold.
    lower, upper = jacobian_bounds(nodes, 3, threshold=0.999 * dense, max_depth=1)
    assert lower[0] <= 0.999 * dense < upper[0]
    assert jacobian_ratio(nodes, 3, threshold=0.9 * dense)[0] > 0.9 * dense


def test_affine_degenerate_and_empty_cells():
    for degree in (1, 2, 3):
        nodes = reference_nodes(degree) @ (TRI * [2.0, 0.5])
        lower, upper = jacobian_bounds(nodes[None], degree)
        assert lower == pytest.approx([1.0]) and upper == pytest.approx([1.0])
        flat = reference_nodes(degree) @ np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
        lower, upper = jacobian_bounds(flat[None], degree)
        assert lower[0] == upper[0] == -np.inf
        empty = np.zeros((0, len(nodes), 2))
        assert [b.shape for b in jacobian_bounds(empty, degree)] == [(0,), (0,)]
    nodes = reference_nodes(1) @ TRI[[0, 2, 1]]  # clockwise: ratio still 1
    assert jacobian_bounds(nodes[None], 1)[0] == pytest.approx([1.0])


def test_resolution_is_deprecated():
    nodes = reference_nodes(2) @ TRI
    with pytest.warns(DeprecationWarning):
        assert jacobian_ratio(nodes[None], 2, 8)[0] == pytest.approx(1.0)


@pytest.mark.parametrize("degree", [2, 3])
def test_many_cells(degree):
    """10 000 mildly curved cells at once (prints the time; no timed assert)."""
    rng = np.random.default_rng(degree)
    nodes = reference_nodes(degree) @ TRI
    bubble = np.arange(len(nodes)) >= 3
    nodes = nodes + 0.02 * rng.standard_normal((10_000,) + nodes.shape) * bubble[:, None]
    jacobian_bounds(nodes[:10], degree)
    t = time.perf_counter()
    lower, upper = jacobian_bounds(nodes, degree)
    print(f"q={degree}: 10000 cells in {1e3 * (time.perf_counter() - t):.1f} ms")
    assert (lower <= upper).all() and (lower > 0).mean() > 0.9


# Tetrahedra: det J of degree 3(q-1), red refinement (eight children) of the undecided leaves.

TET = np.vstack([np.zeros(3), np.eye(3)])


def tet_reference_nodes(degree: int) -> np.ndarray:
    """Barycentric coordinates of the nodes, ``(ndofs, 4)`` (``@ TET``: reference points)."""
    return np.asarray(tet_reference_nodes_lam(degree))


def tet_lattice(n: int) -> np.ndarray:
    i, j, k = np.meshgrid(*[np.arange(n + 1)] * 3, indexing="ij")
    keep = i + j + k <= n
    return np.column_stack([i[keep], j[keep], k[keep]]) / n


def tet_sampled_min(nodes: np.ndarray, degree: int, n: int) -> np.ndarray:
    det = _tet.determinant(
        nodes, lagrange_element("tetrahedron", degree).tabulate(1, tet_lattice(n))[1:, :, :, 0]
    )
    return (det / _tet.affine_determinant(nodes)[:, None]).min(axis=1)


def random_tets(degree: int, m: int, rng: np.random.Generator, amp: float) -> np.ndarray:
    nodes = tet_reference_nodes(degree) @ TET
    return nodes + amp * rng.standard_normal((m,) + nodes.shape)


def random_tet_points(rng: np.random.Generator, n: int) -> np.ndarray:
    p = rng.random((8 * n, 3))
    return p[p.sum(axis=1) <= 1.0][:n]


@pytest.mark.parametrize("degree", [2, 3, 4])
def test_tet_bernstein_coefficients_reproduce_det(degree):
    rng = np.random.default_rng(degree)
    nodes = random_tets(degree, 30, rng, 0.05)
    order = 3 * (degree - 1)
    det = _tet.lattice_determinant(nodes, degree)
    c = _to_bernstein(3, order)(det)
    assert c.shape == (30, (order + 1) * (order + 2) * (order + 3) // 6)
    pts = random_tet_points(rng, 100)
    exact = _tet.determinant(
        nodes, lagrange_element("tetrahedron", degree).tabulate(1, pts)[1:, :, :, 0]
    )
    # collocation matrices of condition 7, 92, 1521 (orders 3, 6, 9): rounding ~1e-13
    assert (
        np.abs(c @ _tet.bernstein_basis(order, pts).T - exact).max() < 1e-11 * np.abs(exact).max()
    )


@pytest.mark.parametrize("degree", [1, 2, 3, 4, 5])
def test_tet_lattice_determinant_is_the_one_product_determinant(degree):
    """The two-product route (derivatives as degree-(q-1) Bernstein polynomials, then
    evaluated) gives det J at the lattice as the direct product does, up to rounding: the
    factors' product is the lattice derivatives, and 1000 cells (two blocks and a part) agree
    to the largest value times 1e-12 (measured: at most 3e-15 at q = 5, sums of O(1) node
    coordinates times derivatives up to 20; the margin is for other CPUs' kernels, while a
    wrong factor or column order gives O(1))."""
    rng = np.random.default_rng(10 + degree)
    d, b = _tet.derivative_factors(degree)
    pts = _tet.control_points(3 * (degree - 1))
    dphi = lagrange_element("tetrahedron", degree).tabulate(1, pts)[1:, :, :, 0]  # (3, p, n)
    n = dphi.shape[2]
    assert np.allclose(
        (d.reshape(n, 3, -1) @ b).transpose(1, 2, 0), dphi, rtol=0, atol=1e-12 * np.abs(dphi).max()
    )
    nodes = random_tets(degree, 1000, rng, 0.05)
    exact = _tet.determinant(nodes, dphi)
    assert (
        np.abs(_tet.lattice_determinant(nodes, degree) - exact).max() < 1e-12 * np.abs(exact).max()
    )


@pytest.mark.parametrize("order", [0, 1, 3, 6, 9])
def test_tet_subdivision_is_exact(order):
    """Child coefficients reproduce the parent on each of the eight children (which tile the
    reference tetrahedron); the operators are convex combinations."""
    rng = np.random.default_rng(order)
    nb = len(_tet.bernstein_indices(order))
    c = rng.standard_normal((3, nb))
    split = _tet.subdivision(order).reshape(nb, 8, 2, nb)
    ref = random_tet_points(rng, 20)
    lam = np.column_stack([1.0 - ref.sum(axis=1), ref])
    volumes = []
    for k, child in enumerate(_tet.CHILDREN):
        want = c @ _tet.bernstein_basis(order, lam @ child).T
        got = (c @ split[:, k, 1]) @ _tet.bernstein_basis(order, ref).T
        assert np.abs(got - want).max() < 1e-12
        ctrl = _tet.bernstein_indices(order) / max(order, 1) @ child
        assert np.allclose(c @ split[:, k, 0], c @ _tet.bernstein_basis(order, ctrl).T, atol=1e-12)
        volumes.append(abs(np.linalg.det(child[1:] - child[0])))
    assert np.allclose(volumes, 1 / 8)
    assert split[:, :, 1].min() >= 0.0
    assert np.abs(split[:, :, 1].sum(axis=0) - 1.0).max() < 1e-15


@pytest.mark.parametrize("degree", [2, 3, 4])
def test_tet_bounds_bracket_the_minimum(degree):
    rng = np.random.default_rng(20 + degree)
    nodes = np.concatenate([random_tets(degree, 40, rng, a) for a in (0.02, 0.06, 0.12)])
    lower, upper = jacobian_bounds(nodes, degree)
    dense = tet_sampled_min(nodes, degree, 36)
    assert (lower <= dense + 1e-11).all()
    assert (lower <= upper).all()
    assert (upper - lower <= 0.05 * np.maximum(np.abs(upper), 0.01) + 1e-11).all()
    assert (lower > 0).any() and (upper <= 0).any()  # both kinds of cell are in the sample
    # every evaluated point lies on the lattice of order * 2^depth subdivisions
    lower, upper = jacobian_bounds(nodes, degree, max_depth=2)
    dense = tet_sampled_min(nodes, degree, 3 * (degree - 1) * 4)
    assert (lower <= dense + 1e-11).all() and (dense <= upper + 1e-11).all()


def test_tet_inverted_and_nearly_degenerate():
    nodes = tet_reference_nodes(2) @ TET
    mid = 4 + 5  # the mid-node of edge 5 (v0 - v1), at (1/2, 0, 0)
    for push, valid in ((0.1, True), (0.2, False)):  # det J = 1 - 8 push at v1
        cell = nodes.copy()
        cell[mid] += push * np.array([0.0, 1.0, 1.0])  # into the cell
        lower, upper = jacobian_bounds(cell[None], 2)
        dense = tet_sampled_min(cell[None], 2, 60)[0]
        # The minimum, 0.2 (or -0.6), is attained at v1, whose corner coefficient is the
        # lower bound: both are that value up to rounding, in either order (1e-12 is far
        # above the ~1e-15 of either, far below the 0.8 that push changes them by).
        assert lower[0] <= dense + 1e-12 and dense <= upper[0] + 1e-12
        assert (lower[0] > 0) == valid and (upper[0] > 0) == valid
        assert jacobian_ratio(cell[None], 2)[0] == pytest.approx(lower[0])


def test_tet_affine_degenerate_and_empty_cells():
    for degree in (1, 2, 3):
        nodes = tet_reference_nodes(degree) @ (TET * [2.0, 0.5, 1.5])
        lower, upper = jacobian_bounds(nodes[None], degree)
        assert lower == pytest.approx([1.0]) and upper == pytest.approx([1.0])
        flat = tet_reference_nodes(degree) @ (TET * [1.0, 1.0, 0.0])
        lower, upper = jacobian_bounds(flat[None], degree)
        assert lower[0] == upper[0] == -np.inf
        empty = np.zeros((0, len(nodes), 3))
        assert [b.shape for b in jacobian_bounds(empty, degree)] == [(0,), (0,)]


@pytest.mark.parametrize("degree", [2, 3, 4])
def test_tet_many_cells_adaptive(degree):
    """5000 mildly curved tetrahedra: only the leaves the coefficients leave undecided or
    loose are split (prints the time; no timed assert)."""
    rng = np.random.default_rng(degree)
    nodes = tet_reference_nodes(degree) @ TET
    bubble = np.arange(len(nodes)) >= 4
    amp = 0.04 / degree**2  # node spacing 1 / q, derivatives of the bubbles ~ q^2
    nodes = nodes + amp * rng.standard_normal((5000,) + nodes.shape) * bubble[:, None]
    jacobian_bounds(nodes[:10], degree)
    t = time.perf_counter()
    lower, upper = jacobian_bounds(nodes, degree)
    print(f"q={degree}: 5000 tetrahedra in {1e3 * (time.perf_counter() - t):.1f} ms")
    assert (lower <= upper).all() and (lower > 0).mean() > 0.9


@pytest.mark.parametrize("tdim", [2, 3])
def test_change_of_basis_is_accurate_up_to_the_highest_degree(tdim):
    """At every degree allowed (MAX_DEGREE) the Bernstein coefficients of a known polynomial
    come back from its values at the control points to 2e-10, on any CPU: measured at most
    1.6e-11 (triangles, q = 7) and 2.8e-11 (tetrahedra, q = 5) with five OpenBLAS core types
    (Zen uses Haswell's). Multiplying by the explicit inverse there, as before, lost 8.7e-10
    to 6.0e-9 depending on the kernel: 2e-10 tells the two apart on every one of them."""
    rng = np.random.default_rng(tdim)
    errors = {}
    for q in range(2, MAX_DEGREE[tdim] + 1):
        order = tdim * (q - 1)
        if tdim == 2:
            basis = bernstein_basis(order, bernstein_indices(order)[:, 1:] / order)
        else:
            basis = _tet.bernstein_basis(order, _tet.control_points(order))
        c = rng.uniform(0.5, 1.5, size=(20, len(basis)))
        errors[q] = np.abs(_to_bernstein(tdim, order)(c @ basis.T) - c).max()
    assert max(errors.values()) < 2e-10, errors
    # the route measured at the top degree is the LU one (rows of the inverse sum to more
    # than _INVERSE_UP_TO there)
    assert _to_bernstein(tdim, tdim * (MAX_DEGREE[tdim] - 1)).lu is not None


@pytest.mark.parametrize("tdim", [2, 3])
def test_degrees_above_the_limit_are_refused(tdim):
    top = MAX_DEGREE[tdim]
    assert check_degree(top, tdim) == top and check_degree(2.0, tdim) == 2
    for bad in (0, 2.5, True, top + 1):
        with pytest.raises(ValueError, match="geometry degree"):
            check_degree(bad, tdim)
    nodes = reference_nodes(top + 1) @ TRI if tdim == 2 else tet_reference_nodes(top + 1) @ TET
    with pytest.raises(ValueError, match=f"above {top}, the highest"):
        jacobian_bounds(nodes[None], top + 1)
