"""Tetrahedron kernels: every vectorised function against a slow per-cell reference."""

from __future__ import annotations

import itertools
from fractions import Fraction

import numpy as np
import pytest

from dolfinx_universal.cells.tet import (
    DIHEDRAL_BIN_EDGES,
    EDGES,
    FACETS,
    TARGET_MEAN_RATIO,
    StarFaces,
    cell_diameters,
    dihedral_angles,
    directions,
    edge_lengths,
    facets,
    mean_ratio,
    quality_summary,
    radius_ratio,
    signed_volumes,
    star_entries,
    star_faces,
    star_quality,
    tangent_directions,
)

BASIX_EDGES = [(2, 3), (1, 3), (1, 2), (0, 3), (0, 2), (0, 1)]
BASIX_FACETS = [(1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)]
REGULAR = np.array([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])  # edge 2 sqrt 2
RIGHT = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])  # reference tetrahedron
BCC = np.array([[0.5, 0.5, 0.5], [1.5, 0.5, 0.5], [1, 0, 0], [1, 1, 0]])  # 2 cube centres
# The mean ratio's reference: the regular tetrahedron of unit edge, as columns x_i - x_0.
W = np.array([[1.0, 0.5, 0.5], [0.0, np.sqrt(3) / 2, np.sqrt(3) / 6], [0, 0, np.sqrt(2 / 3)]])


# ---------------------------------------------------------------- slow references (loops)


def ref_volume(P):
    return np.linalg.det(np.column_stack([np.ones(4), P])) / 6.0


def ref_edges(P):
    return np.array([np.linalg.norm(P[j] - P[i]) for i, j in BASIX_EDGES])


def ref_dihedral(P):
    """Angle between the parts of the two other corners' offsets perpendicular to the edge."""
    out = []
    for i, j in BASIX_EDGES:
        k, m = (v for v in range(4) if v not in (i, j))
        e = P[j] - P[i]
        e = e / np.linalg.norm(e)
        u = P[k] - P[i]
        w = P[m] - P[i]
        u, w = u - (u @ e) * e, w - (w @ e) * e
        out.append(np.arctan2(np.linalg.norm(np.cross(u, w)), u @ w))
    return np.array(out)


def ref_mean_ratio(P):
    """``3 det(S)^(2/3) / |S|_F^2`` of ``S = J W^-1`` (Knupp), signed by ``det S``."""
    J = (P[1:] - P[0]).T
    S = J @ np.linalg.inv(W)
    d = np.linalg.det(S)
    return np.sign(d) * 3.0 * abs(d) ** (2.0 / 3.0) / np.sum(S * S)


def ref_radius_ratio(P):
    A = 2.0 * (P[1:] - P[0])
    c = np.linalg.solve(A, (P[1:] ** 2).sum(axis=1) - P[0] @ P[0])
    R = np.linalg.norm(c - P[0])
    area = sum(0.5 * np.linalg.norm(np.cross(P[b] - P[a], P[d] - P[a])) for a, b, d in FACETS)
    return 3.0 * (3.0 * abs(ref_volume(P)) / area) / R


def per_cell(f, x, cells):
    return np.array([f(x[c]) for c in cells])


# ---------------------------------------------------------------- test meshes


def random_tets(rng, m, *, scale=1.0, offset=0.0):
    """Random tetrahedra with shared vertices, about half of them inverted."""
    x = offset + scale * rng.random((3 * m, 3))
    cells = np.array([rng.choice(len(x), 4, replace=False) for _ in range(m)])
    return x, cells


def near_degenerate(rng):
    """Flat-ish, needle, sliver, cap and wedge tetrahedra (both orientations), (8 k, 4)."""
    pts = []
    for _ in range(20):
        s = 10.0 ** rng.uniform(-7, -3)
        q = rng.random((3, 3))
        pts.append(np.vstack([q, q.mean(axis=0) + s * rng.standard_normal(3)]))  # cap
        pts.append(np.vstack([q, q[0] + s * rng.standard_normal(3)]))  # needle
        sq = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
        sq[[0, 2], 2] += s
        pts.append(sq + 0.1 * s * rng.standard_normal((4, 3)))  # sliver
        t = rng.random()
        pts.append(np.vstack([q, q[0] + t * (q[1] - q[0]) + s * rng.standard_normal(3)]))  # wedge
    pts = [p[[0, 2, 1, 3]] if i % 2 else p for i, p in enumerate(pts)]
    x = np.vstack(pts)
    return x, np.arange(len(x)).reshape(-1, 4)


@pytest.fixture(scope="module")
def rand():
    return random_tets(np.random.default_rng(1), 300)


@pytest.fixture(scope="module")
def degen():
    return near_degenerate(np.random.default_rng(2))


def one(P):
    return np.asarray(P, dtype=np.float64), np.array([[0, 1, 2, 3]])


# ---------------------------------------------------------------- numbering


def test_numbering_is_basix():
    basix = pytest.importorskip("basix")
    topo = basix.topology(basix.CellType.tetrahedron)
    assert EDGES.tolist() == topo[1] == [list(e) for e in BASIX_EDGES]
    assert [sorted(f) for f in FACETS.tolist()] == topo[2]
    for k, f in enumerate(FACETS.tolist()):
        perm = [k, *f]  # (k, a, b, c) an even permutation of (0, 1, 2, 3)
        inversions = sum(perm[i] > perm[j] for i, j in itertools.combinations(range(4), 2))
        assert inversions % 2 == 0


# ---------------------------------------------------------------- against the references


def test_volumes_edges_diameters(rand, degen):
    for x, cells in (rand, degen):
        V = signed_volumes(x, cells)
        ref = per_cell(ref_volume, x, cells)
        assert np.allclose(V, ref, rtol=1e-10, atol=1e-15)
        assert np.allclose(edge_lengths(x, cells), per_cell(ref_edges, x, cells), rtol=1e-14)
        assert np.allclose(cell_diameters(x, cells), per_cell(ref_edges, x, cells).max(axis=1))
    x, cells = rand
    assert 0.3 < np.mean(signed_volumes(x, cells) > 0) < 0.7  # both orientations tested
    x, cells = one(RIGHT)
    assert signed_volumes(x, cells)[0] == pytest.approx(1.0 / 6.0)  # reference: positive
    assert signed_volumes(x, cells[:, [0, 2, 1, 3]])[0] == pytest.approx(-1.0 / 6.0)


def test_dihedral_angles(rand, degen):
    x, cells = rand
    assert np.allclose(dihedral_angles(x, cells), per_cell(ref_dihedral, x, cells), atol=1e-12)
    x, cells = degen
    got, ref = dihedral_angles(x, cells), per_cell(ref_dihedral, x, cells)
    assert np.isfinite(got).all()
    assert np.allclose(got, ref, atol=1e-7)
    assert got.min() < 1e-3 and got.max() > np.pi - 1e-3
    # The six angles of a tetrahedron and of its reflection (inverted) are the same.
    assert np.allclose(dihedral_angles(-x, cells), got, atol=1e-7)
    # Inverted or not: the same angles at the same edges (the edge (0, 1) keeps its column).
    x, cells = rand
    swapped = cells[:, [1, 0, 2, 3]]  # edges permute: (2,3) (0,3) (0,2) (1,3) (1,2) (0,1)
    ref = per_cell(ref_dihedral, x, cells)
    assert np.allclose(dihedral_angles(x, swapped)[:, [0, 3, 4, 1, 2, 5]], ref, atol=1e-12)


def test_dihedral_undefined_and_flat():
    # Flat, with facets of positive area: angles 0 or pi, and they add up to 2 pi (a
    # convex quadrilateral with its diagonals: 2 at pi, 4 at 0).
    x, cells = one([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    a = dihedral_angles(x, cells)[0]
    assert np.isfinite(a).all()
    assert sorted(np.round(a / np.pi, 12).tolist()) == [0, 0, 0, 0, 1, 1]
    # A collapsed edge (0, 1): the facets opposite vertices 2 and 3 contain it and have
    # zero area, so only the angle at edge (2, 3) (between facets 0 and 1) is defined.
    x, cells = one([[0.0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0.5]])
    a = dihedral_angles(x, cells)[0]
    undefined = [e for e in range(6) if {2, 3} & set(EDGES[5 - e])]
    assert undefined == [1, 2, 3, 4, 5] and np.isnan(a[undefined]).all()
    assert np.isfinite(np.delete(a, undefined)).all()


def test_mean_and_radius_ratio(rand, degen):
    for x, cells in (rand, degen):
        mr, rr = mean_ratio(x, cells), radius_ratio(x, cells)
        assert np.allclose(mr, per_cell(ref_mean_ratio, x, cells), rtol=1e-9, atol=1e-12)
        assert np.allclose(rr, per_cell(ref_radius_ratio, x, cells), rtol=1e-7, atol=1e-12)
        V = signed_volumes(x, cells)
        assert np.array_equal(np.sign(mr), np.sign(V))
        assert (np.abs(mr) <= 1 + 1e-12).all() and (rr >= 0).all() and (rr <= 1 + 1e-12).all()
    # Similarity invariance: scaled, turned, translated.
    x, cells = rand
    Q, _ = np.linalg.qr(np.random.default_rng(3).standard_normal((3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    y = 1e-3 * x @ Q.T + 5.0
    assert np.allclose(mean_ratio(y, cells), mean_ratio(x, cells), rtol=1e-8)
    assert np.allclose(radius_ratio(y, cells), radius_ratio(x, cells), rtol=1e-8)
    # Flat and collapsed cells: 0, without warnings.
    x = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    with np.errstate(all="raise"):
        for c in ([0, 1, 2, 3], [0, 0, 0, 0], [0, 0, 1, 2]):
            assert mean_ratio(x, np.array([c]))[0] == 0.0
            assert radius_ratio(x, np.array([c]))[0] == 0.0


def test_known_values():
    x, cells = one(REGULAR)
    if signed_volumes(x, cells)[0] < 0:
        cells = cells[:, [1, 0, 2, 3]]
    assert mean_ratio(x, cells)[0] == pytest.approx(1.0, rel=1e-14)
    assert mean_ratio(x, cells[:, [1, 0, 2, 3]])[0] == pytest.approx(-1.0, rel=1e-14)
    assert radius_ratio(x, cells)[0] == pytest.approx(1.0, rel=1e-14)
    assert np.allclose(dihedral_angles(x, cells), np.arccos(1.0 / 3.0), rtol=1e-14)
    assert np.degrees(np.arccos(1.0 / 3.0)) == pytest.approx(70.5288, abs=1e-4)
    assert np.allclose(edge_lengths(x, cells), 2.0 * np.sqrt(2.0))
    # BCC: dihedral 90 degrees at the 2 edges of length h, 60 at the 4 of length sqrt(3)/2 h.
    x, cells = one(BCC)
    e, a = edge_lengths(x, cells)[0], np.degrees(dihedral_angles(x, cells)[0])
    assert np.allclose(a[np.isclose(e, 1.0)], 90.0) and np.isclose(e, 1.0).sum() == 2
    assert np.allclose(a[np.isclose(e, np.sqrt(3) / 2)], 60.0)
    assert abs(mean_ratio(x, cells)[0]) == pytest.approx(0.9524, abs=1e-4)  # research notes
    # The right-corner (reference) tetrahedron.
    x, cells = one(RIGHT)
    a = np.degrees(dihedral_angles(x, cells)[0])
    assert np.allclose(a, [54.7356103] * 3 + [90.0] * 3)  # EDGES: (2,3) (1,3) (1,2) at 0
    assert mean_ratio(x, cells)[0] == pytest.approx(12.0 * 0.5 ** (2 / 3) / 9.0, rel=1e-14)
    assert radius_ratio(x, cells)[0] == pytest.approx(np.sqrt(3.0) - 1.0, rel=1e-14)
    assert cell_diameters(x, cells)[0] == pytest.approx(np.sqrt(2.0))


# ---------------------------------------------------------------- facets and star entries


def kuhn_cube():
    """A unit cube in 6 tetrahedra around its diagonal (both orientations)."""
    x = np.array(list(itertools.product([0.0, 1.0], repeat=3)))
    idx = {tuple(p): i for i, p in enumerate(x.astype(int).tolist())}
    cells = []
    for perm in itertools.permutations(range(3)):
        p, c = [0, 0, 0], [idx[(0, 0, 0)]]
        for axis in perm:
            p[axis] = 1
            c.append(idx[tuple(p)])
        cells.append(c)
    return x, np.array(cells)


def test_facets_outward(rand):
    x, cells = rand
    V = signed_volumes(x, cells)
    f = facets(cells)
    assert f.shape == (len(cells), 4, 3)
    for i, c in enumerate(cells):
        for k in range(4):
            assert sorted(f[i, k]) == sorted(np.delete(c, k))
    P = x[f]
    n = np.cross(P[:, :, 1] - P[:, :, 0], P[:, :, 2] - P[:, :, 0])
    side = np.einsum("mkd,mkd->mk", x[cells] - P[:, :, 0], n)  # vertex k from its facet
    assert (side[V > 0] < 0).all() and (side[V < 0] > 0).all()
    fo = facets(cells, np.sign(V))
    P = x[fo]
    n = np.cross(P[:, :, 1] - P[:, :, 0], P[:, :, 2] - P[:, :, 0])
    assert (np.einsum("mkd,mkd->mk", x[cells] - P[:, :, 0], n) < 0).all()
    assert np.array_equal(fo[V > 0], f[V > 0])
    with pytest.raises(ValueError):
        facets(cells, np.ones(3))


def test_facets_orient_boundary():
    """The facets seen once are the cube's boundary, outward; the others pair up reversed."""
    x, cells = kuhn_cube()
    V = signed_volumes(x, cells)
    assert (V < 0).any() and (V > 0).any() and np.allclose(np.abs(V).sum(), 1.0)
    f = facets(cells, np.sign(V)).reshape(-1, 3)
    key = [tuple(sorted(t)) for t in f.tolist()]
    count = {k: key.count(k) for k in key}
    bnd = np.array([count[k] == 1 for k in key])
    assert bnd.sum() == 12  # 2 triangles per square face
    P = x[f]
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    out = np.einsum("fd,fd->f", n, P.mean(axis=1) - 0.5)
    assert (out[bnd] > 0).all()
    assert np.allclose(n[bnd].sum(axis=0), 0.0)  # closed surface
    for k in {k for k in key if count[k] == 2}:
        a, b = (f[i] for i in range(len(f)) if key[i] == k)
        rot = [np.roll(b[::-1], s).tolist() for s in range(3)]
        assert a.tolist() in rot  # the two copies of an interior facet are reversed


def test_star_entries_match_mean_ratio(rand, degen):
    for x, cells in (rand, degen):
        V = signed_volumes(x, cells)
        mr = mean_ratio(x, cells)
        for orientation in (None, np.sign(V)):
            sgn = np.ones(len(cells)) if orientation is None else orientation
            vert, face = star_entries(cells, orientation)
            assert np.array_equal(vert, cells)
            p = x[vert]
            fc = star_faces(x[face[..., 0]], x[face[..., 1]], x[face[..., 2]])
            q = star_quality(p[..., 0], p[..., 1], p[..., 2], fc)
            expect = np.where(sgn * V > 0, sgn * mr / TARGET_MEAN_RATIO, -1.0)[:, None]
            assert np.allclose(q, np.broadcast_to(expect, q.shape), rtol=1e-9, atol=1e-12)
            qs = star_quality(p[..., 0], p[..., 1], p[..., 2], fc, signed=True)
            assert np.allclose(qs, (sgn * mr)[:, None] / TARGET_MEAN_RATIO, atol=1e-12)
            fc1 = star_faces(x[face[..., 0]], x[face[..., 1]], x[face[..., 2]], target=1.0)
            q1 = star_quality(p[..., 0], p[..., 1], p[..., 2], fc1, signed=True)
            assert np.allclose(q1, (sgn * mr)[:, None], atol=1e-12)


def exact_mean_ratio(P):
    """Signed mean ratio and height of the tetrahedron ``P``, in exact rational arithmetic.

    Also returns the distance of ``P[0]`` from the plane of the other three.
    """
    F = [[Fraction(float(v)) for v in row] for row in P]
    d = [[F[i][k] - F[0][k] for k in range(3)] for i in (1, 2, 3)]
    v6 = (
        d[0][0] * (d[1][1] * d[2][2] - d[1][2] * d[2][1])
        - d[0][1] * (d[1][0] * d[2][2] - d[1][2] * d[2][0])
        + d[0][2] * (d[1][0] * d[2][1] - d[1][1] * d[2][0])
    )
    lsum = sum(sum((F[j][k] - F[i][k]) ** 2 for k in range(3)) for i, j in BASIX_EDGES)
    v6f = float(v6)
    mr = np.sign(v6f) * 12.0 * (0.5 * abs(v6f)) ** (2.0 / 3.0) / float(lsum)
    n = np.cross(P[2] - P[1], P[3] - P[1])
    return mr, abs(v6f) / np.linalg.norm(n)


def test_star_quality_candidates(rand):
    """Candidates (ne, nc) against entry arrays (ne,), also far from the origin."""
    rng = np.random.default_rng(4)
    x, cells = rand
    vert, face = star_entries(cells, np.sign(signed_volumes(x, cells)))
    vert, face = vert.reshape(-1)[:400], face.reshape(-1, 3)[:400]
    nc = 5
    for offset, scale in ((0.0, 1.0), (100.0, 1e-3)):
        y = offset + scale * x
        p = y[vert][:, None, :] + 0.3 * scale * rng.standard_normal((len(vert), nc, 3))
        a, b, c = (y[face[:, i]] for i in range(3))
        fc = star_faces(a, b, c, target=0.5)
        q = star_quality(p[..., 0], p[..., 1], p[..., 2], fc)  # fields get a trailing axis
        assert q.shape == (len(vert), nc)
        qs = star_quality(p[..., 0], p[..., 1], p[..., 2], fc.select(slice(None), 1))
        assert np.array_equal(qs, q)
        # Candidate-major layout (nc, ne), the fields (1, ne).
        pt = np.ascontiguousarray(p.transpose(1, 0, 2))
        ft = StarFaces(*(v[None] for v in fc))
        assert np.array_equal(star_quality(pt[..., 0], pt[..., 1], pt[..., 2], ft), q.T)
        ref, height = np.empty_like(q), np.empty_like(q)
        for i, j in np.ndindex(q.shape):
            P = np.vstack([p[i, j], a[i], b[i], c[i]])
            mr, height[i, j] = exact_mean_ratio(P)
            ref[i, j] = mr / 0.5 if mr > 0 else -1.0
        valid = ref > -1
        assert 0.3 < valid.mean() < 0.95
        assert np.array_equal(q > -1, valid)
        # The centroid's rounding (eps |g|) moves the height of p above the facet.
        rtol = 1e-14 + 4 * np.finfo(float).eps * (offset + scale) / height
        assert (np.abs(q - ref) <= rtol * np.abs(ref)).all()
        # One candidate per entry, and a selection of entries: the same values.
        q0 = star_quality(p[:, 0, 0], p[:, 0, 1], p[:, 0, 2], fc)
        assert np.array_equal(q0, q[:, 0])
        E = np.array([5, 2, 2, 17])
        qe = star_quality(p[E, :, 0], p[E, :, 1], p[E, :, 2], fc.select(E, 1))
        assert np.array_equal(qe, q[E])
        assert np.array_equal(star_quality(p[E, :, 0], p[E, :, 1], p[E, :, 2], fc.select(E)), qe)


def test_star_quality_degenerate():
    a = np.zeros((3, 3))
    with np.errstate(all="raise"):
        fc = star_faces(a, a, a)  # a facet collapsed to a point
        for p in (np.zeros(3), np.ones(3)):
            assert star_quality(*p[:, None], fc)[0] == -1.0
            assert star_quality(*p[:, None], fc, signed=True)[0] == 0.0
        tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
        fc = star_faces(tri[0], tri[2], tri[1])  # (p, a, b, c) positive for p above z = 0
        pz = np.array([1.0, 0.0, -1.0])
        assert np.array_equal(star_quality(0.0 * pz, 0.0 * pz, pz, fc)[1:], [-1.0, -1.0])
        assert star_quality(0.0 * pz, 0.0 * pz, pz, fc)[0] > 0
        s = star_quality(0.0 * pz, 0.0 * pz, pz, fc, signed=True)
        assert s[1] == 0.0 and s[2] == pytest.approx(-s[0])
    x, cells = one(REGULAR)
    if signed_volumes(x, cells)[0] < 0:
        cells = cells[:, [1, 0, 2, 3]]
    _, face = star_entries(cells)
    fc = star_faces(*(x[face[0, 0, i]] for i in range(3)))
    p = x[cells[0, 0]]
    assert star_quality(*p[:, None], fc)[0] == pytest.approx(1.0 / TARGET_MEAN_RATIO)


# ---------------------------------------------------------------- summary


def test_quality_summary(rand):
    x, cells = rand
    V = signed_volumes(x, cells)
    s = quality_summary(x, cells)
    ang = np.degrees(per_cell(ref_dihedral, x, cells))
    assert s["n_cells"] == len(cells)
    assert s["dihedral_min_deg"] == pytest.approx(ang.min())
    assert s["dihedral_max_deg"] == pytest.approx(ang.max())
    hist = s["dihedral_histogram"]
    assert len(hist) == 18 and len(DIHEDRAL_BIN_EDGES) == 19 and hist.sum() == ang.size
    ref_hist = [((ang >= lo) & (ang < lo + 10)).sum() for lo in range(0, 180, 10)]
    assert np.abs(hist - ref_hist).sum() <= 2  # bin edges up to rounding
    assert s["radius_ratio_min"] == pytest.approx(per_cell(ref_radius_ratio, x, cells).min())
    mr = per_cell(ref_mean_ratio, x, cells)
    assert s["mean_ratio_min"] == pytest.approx(mr.min())
    assert s["n_inverted"] == (V < 0).sum() and s["n_degenerate"] == 0
    s = quality_summary(x, cells, np.sign(V))
    assert s["n_inverted"] == 0 and s["mean_ratio_min"] == pytest.approx(np.abs(mr).min())
    # Known cells, a flat one and one with a collapsed edge.
    y = np.vstack([REGULAR, BCC, RIGHT, [[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]])
    c = np.arange(16).reshape(4, 4)
    c = np.vstack([c, [[12, 12, 13, 14]]])
    c[0] = c[0] if signed_volumes(y, c[:1])[0] > 0 else c[0, [1, 0, 2, 3]]
    c[1] = c[1] if signed_volumes(y, c[1:2])[0] > 0 else c[1, [1, 0, 2, 3]]
    s = quality_summary(y, c)
    assert s["n_inverted"] == 2 and s["n_degenerate"] == 1
    assert s["dihedral_min_deg"] == 0.0 and s["dihedral_max_deg"] == pytest.approx(180.0)
    assert s["radius_ratio_min"] == 0.0 and s["mean_ratio_min"] == 0.0
    assert s["dihedral_histogram"].sum() == 4 * 6 + 1  # 5 angles of the last are nan
    e = quality_summary(y, c[:0])
    assert e["n_cells"] == 0 and e["dihedral_min_deg"] == 180.0 and e["n_inverted"] == 0


# ---------------------------------------------------------------- directions


def test_directions():
    for n in (6, 12, 26):
        d0 = directions(n, 0)
        assert d0.shape == (n, 3)
        assert np.allclose(np.linalg.norm(d0, axis=1), 1.0)
        assert np.array_equal(d0, directions(n, 0))  # deterministic
        gram = d0 @ d0.T
        for sweep in (1, 2, 17):
            d = directions(n, sweep)
            assert np.allclose(d @ d.T, gram)  # a rotation of the same set
            assert not np.allclose(d, d0)
        # Well spread: no two close, and every direction within 70 degrees of one of them
        # (a positive spanning set: the compass can move every way).
        off = gram[~np.eye(n, dtype=bool)]
        assert off.max() < np.cos(np.radians(25.0))
        u = np.random.default_rng(5).standard_normal((4000, 3))
        u /= np.linalg.norm(u, axis=1)[:, None]
        assert (u @ d0.T).max(axis=1).min() > np.cos(np.radians(70.0))
    # Over the sweeps, one direction visits the whole sphere.
    first = np.array([directions(8, s)[0] for s in range(200)])
    assert np.abs(first.mean(axis=0)).max() < 0.1
    octant = (first > 0) @ [1, 2, 4]
    assert len(np.unique(octant)) == 8


def test_tangent_directions():
    rng = np.random.default_rng(6)
    normals = np.vstack(
        [np.eye(3), -np.eye(3), [[1, 1, 1], [1e-9, 0, -3], [0.6, 0.8, 0]], rng.normal(size=(20, 3))]
    )
    nhat = normals / np.linalg.norm(normals, axis=1)[:, None]
    n = 8
    t = tangent_directions(normals, n, 0)
    assert t.shape == (len(normals), n, 3)
    assert np.allclose(np.linalg.norm(t, axis=2), 1.0)
    assert np.allclose(np.einsum("knd,kd->kn", t, nhat), 0.0, atol=1e-15)
    for k in range(len(normals)):  # equally spaced, turning right-handedly about the normal
        for j in range(n):
            a, b = t[k, j], t[k, (j + 1) % n]
            assert a @ b == pytest.approx(np.cos(2 * np.pi / n))
            assert np.cross(a, b) @ nhat[k] == pytest.approx(np.sin(2 * np.pi / n))
    golden = np.pi * (3 - np.sqrt(5))
    t1 = tangent_directions(normals, n, 1)
    assert np.allclose(np.einsum("knd,knd->kn", t, t1), np.cos(golden))
    assert np.allclose(np.einsum("knd,kd->kn", np.cross(t, t1), nhat), np.sin(golden))
    assert tangent_directions(np.zeros((0, 3)), n, 3).shape == (0, n, 3)
