"""The vectorised classification and M_h against slow, obvious per-cell references."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dolfinx_universal.backgrounds.lattice_tri import equilateral_triangulation
from dolfinx_universal.conforming import classify as classify


def _setup(seed: int):
    """A jittered equilateral triangulation and a circle's signs/distances on it."""
    rng = np.random.default_rng(seed)
    x, cells = equilateral_triangulation([[-1.3, -1.3], [1.3, 1.3]], 0.2)
    x = x + rng.uniform(-0.02, 0.02, x.shape)
    c = rng.uniform(-0.1, 0.1, 2)
    d = np.linalg.norm(x - c, axis=1)
    phi = d - 1.0
    s = np.where(phi < 0, -1.0, 1.0)
    return x, cells, s, phi, c


def _angle(p, q, r):
    """Interior angle at p of triangle p, q, r."""
    a, b = q - p, r - p
    return math.acos(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_positive_edges_and_conditioning_angles(seed):
    x, cells, s, phi, _ = _setup(seed)
    pc = classify.positively_cut(s, cells)
    kept = classify.kept_cells(s, cells)
    u, v, w = classify.positive_edges(s, cells[pc])
    theta = classify.conditioning_angle(x, phi, u, v, w)
    prox = classify.proximal_vertex(x, phi, u, v, w)
    j = 0
    for i, cell in enumerate(cells):  # the slow reference, one cell at a time
        signs = [s[a] for a in cell]
        assert kept[i] == (min(signs) < 0)
        assert pc[i] == (signs.count(1.0) == 2)
        if not pc[i]:
            continue
        inside = cell[signs.index(-1.0)]
        edge = sorted(a for a in cell if a != inside)
        assert sorted([u[j], v[j]]) == edge and w[j] == inside
        # (u, v, w) keeps the cell's orientation: same signed area sign.
        tri = [cell[k] for k in range(3)]
        assert np.sign(classify.signed_areas(x, np.array([[u[j], v[j], w[j]]]))[0]) == np.sign(
            classify.signed_areas(x, np.array([tri]))[0]
        )
        a, b = edge
        p = a if abs(phi[a]) < abs(phi[b]) else b
        assert prox[j] == p
        others = [q for q in cell if q != p]
        # acos and arctan2 of the same angle (near 60 degrees, well conditioned): a few ulps
        assert theta[j] == pytest.approx(_angle(x[p], x[others[0]], x[others[1]]), abs=1e-12)
        j += 1


def test_proximal_tie_goes_to_smaller_angle():
    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.2, -0.8]])
    phi = np.array([0.1, 0.1, -0.5])
    u, v, w = np.array([0]), np.array([1]), np.array([2])
    # angle at 0 is larger than at 1 (apex is near vertex 0): vertex 1 is proximal.
    assert classify.proximal_vertex(x, phi, u, v, w)[0] == 1


@pytest.mark.parametrize("eta", [0.05, 0.2, 0.5])
def test_perturbation_candidates(eta):
    x, cells, s, phi, _ = _setup(3)
    got = classify.perturbation_candidates(x, phi, s, cells, eta)
    expected = set()
    for cell in cells:
        if sorted(s[cell].tolist()) != [-1.0, 1.0, 1.0]:
            continue
        a, b, c = sorted(cell, key=lambda q: -phi[q])
        hk = max(np.linalg.norm(x[p] - x[q]) for p in cell for q in cell)
        if phi[b] - phi[c] < eta * hk:
            expected.add(c)
    assert set(got.tolist()) == expected


def test_straight_map():
    x, cells, s, phi, c = _setup(4)
    d = x - c
    n = d / np.linalg.norm(d, axis=1)[:, None]
    closest = c + n
    pc = classify.positively_cut(s, cells)
    u, v, _ = classify.positive_edges(s, cells[pc])
    on_pe = np.zeros(len(x), dtype=bool)
    on_pe[np.concatenate([u, v])] = True
    h, Rr, alpha = 0.2, 0.6, 0.75
    y = classify.straight_map(
        x, phi, closest, n, on_pe, np.full(len(x), h), np.full(len(x), Rr), alpha
    )
    for i in range(len(x)):
        if on_pe[i]:
            f = phi[i]
        elif phi[i] < 0:
            f = alpha * h * max(0.0, 1 + phi[i] / Rr)
        else:
            f = 0.0
        assert np.allclose(y[i], x[i] - f * n[i], rtol=0, atol=1e-14)  # x - f n: an ulp or two


def test_quality_measures_equilateral():
    from dolfinx_universal.conforming.quality import edge_ratio, radius_ratio

    x = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, np.sqrt(3) / 2], [0.0, 1.0]])
    cells = np.array([[0, 1, 2], [0, 1, 3]])
    assert radius_ratio(x, cells)[0] == pytest.approx(2.0)
    assert edge_ratio(x, cells)[0] == pytest.approx(1.0)
    # right isosceles: R = sqrt(2)/2, r = (2 - sqrt(2))/2
    assert radius_ratio(x, cells)[1] == pytest.approx(np.sqrt(2) / (2 - np.sqrt(2)))
    assert np.allclose(np.degrees(classify.interior_angles(x, cells)[0]), 60.0)
