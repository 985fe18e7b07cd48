"""The directional vertex relaxation of tetrahedra (dolfinx_universal.conforming.relax_tet)."""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest

from dolfinx_universal.backgrounds.lattice_tet import a15_tetrahedralisation
from dolfinx_universal.cells import tet as tet
from dolfinx_universal.conforming import relax_tet as _dvr


class _SerialMap:
    """The vertex index map of one rank: :class:`relax_common.SubVertices` reads only its
    communicator."""

    comm = MPI.COMM_SELF


def _star_data(p, face):
    """``u = p - g``, ``s``, ``L`` of the entries ``(p, face)`` at ``t = 0``."""
    u = (p[:, 0] - face.gx, p[:, 1] - face.gy, p[:, 2] - face.gz)
    s = u[0] * face.nx + u[1] * face.ny + u[2] * face.nz
    L = u[0] ** 2 + u[1] ** 2 + u[2] ** 2 + face.lsq
    return u, s, L


def _random_entries(rng, n):
    """Random entries ``(p, a, b, c)``: valid, inverted, flat and coincident facets."""
    p = rng.standard_normal((n, 3))
    a, b, c = (rng.standard_normal((n, 3)) for _ in range(3))
    k = n // 8
    c[:k] = a[:k] + 0.7 * (b[:k] - a[:k])  # collinear facets
    b[k : 2 * k] = a[k : 2 * k]  # two coincident corners
    b[2 * k : 3 * k] = c[2 * k : 3 * k] = a[2 * k : 3 * k]  # a point
    p[3 * k : 4 * k] = a[3 * k : 4 * k] + 0.5 * (b[3 * k : 4 * k] - a[3 * k : 4 * k])  # flat
    return p, a, b, c


def test_cube_root_is_portable_and_accurate():
    """The relaxation's cube root: within 4 ulps of numpy's over the whole positive range
    (subnormals included), and computed from IEEE
    operations only (checked here: the same bits as the recurrence in Python floats)."""
    rng = np.random.default_rng(5)
    x = np.concatenate(
        [rng.uniform(0.0, 2.0, 20000), 10.0 ** rng.uniform(-323, 307, 20000), [5e-324, 1e-310]]
    )
    x = x[x > 0]
    c = _dvr.cube_root(x)
    assert np.all(np.abs(c - np.cbrt(x)) <= 4 * np.spacing(np.cbrt(x)))
    # The same recurrence on Python floats (no numpy kernels): bitwise the same.
    import struct

    for xi, ci in zip(x[::997], c[::997], strict=True):
        xs = xi * 2.0**54 if xi < np.finfo(float).tiny else xi
        bits = struct.unpack("<Q", struct.pack("<d", xs))[0] // 3 + 0x2A9F7893782DA1CE
        t = struct.unpack("<d", struct.pack("<Q", bits % 2**64))[0]
        for _ in range(3):
            t3 = t * t * t
            t = t * ((t3 + (xs + xs)) / ((t3 + t3) + xs))
        assert (t * 2.0**-18 if xi < np.finfo(float).tiny else t) == ci


def test_ratings_order_as_qualities():
    """The ratings ``s^2 / L^3`` (the cubes of the qualities) and their qualities
    ``cbrt(r)`` are those of :func:`_tetrahedron.star_quality`, to rounding, -1 at the same
    entries."""
    rng = np.random.default_rng(12)
    p, a, b, c = _random_entries(rng, 4000)
    face = tet.star_faces(a, b, c)
    _, s, L = _star_data(p, face)
    r = _dvr.rating(s, L)
    q = _dvr.rating_quality(r)
    ref = tet.star_quality(p[:, 0], p[:, 1], p[:, 2], face)
    valid = ref > -1
    assert np.array_equal(r > 0, valid) and np.all(q[~valid] == -1.0) and valid.mean() > 0.3
    assert np.all(np.abs(q[valid] - ref[valid]) <= 1e-14 * ref[valid])


def test_line_quality_is_star_quality():
    """The closed form along ``p + t d`` equals the kernel evaluated at those points."""
    rng = np.random.default_rng(11)
    n = 4000
    p, a, b, c = _random_entries(rng, n)
    face = tet.star_faces(a, b, c)
    u, s, L = _star_data(p, face)
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    sig = d[:, 0] * face.nx + d[:, 1] * face.ny + d[:, 2] * face.nz
    beta2 = 2.0 * (d[:, 0] * u[0] + d[:, 1] * u[1] + d[:, 2] * u[2])
    t = np.array([0.0, 0.01, 0.1, 0.5, 1.0, 2.0, -0.3])[:, None] * np.ones(n)
    q = _dvr.rating_quality(_dvr.line_rating(s, L, sig, beta2, t))
    x = p[None] + t[..., None] * d[None]
    ref = tet.star_quality(x[..., 0], x[..., 1], x[..., 2], tet.StarFaces(*(v[None] for v in face)))
    assert q.shape == ref.shape == (len(t), n)
    valid = ref > -1
    assert 0.2 < valid.mean() < 0.8
    # Where 6V is small against |u| |n| its relative rounding grows (up to sign flips):
    # compare where it is above 1e-3 |u| |n| (relative rounding below ~1e-13).
    nn = np.sqrt(face.nx**2 + face.ny**2 + face.nz**2)
    ux, uy, uz = (x[..., i] - g for i, g in enumerate((face.gx, face.gy, face.gz)))
    scale = np.sqrt(ux * ux + uy * uy + uz * uz) * nn
    s_t = s + t * sig
    clear = np.abs(s_t) > 1e-3 * scale
    assert clear.mean() > 0.6
    assert np.array_equal((q > -1)[clear], valid[clear])
    both = clear & valid
    assert np.all(np.abs(q[both] - ref[both]) <= 1e-12 * np.abs(ref[both]))
    assert np.all(q[clear & ~valid] == -1.0)
    # Facets with coincident corners (zero normal) rate -1 along every line, collinear
    # ones (a normal of rounding) about 0 or -1.
    k = n // 8
    assert np.all(q[:, k : 3 * k] == -1.0) and np.all(ref[:, k : 3 * k] == -1.0)
    assert np.all(q[:, :k] < 1e-9) and np.all(ref[:, :k] < 1e-9)


def _perturbed_a15(seed, amplitude=0.2):
    """An A15 patch of size 1 with its inner vertices moved by ``amplitude`` at random."""
    rng = np.random.default_rng(seed)
    x, cells = a15_tetrahedralisation([[0, 0, 0], [3, 3, 3]], 1.0)
    lo, hi = x.min(axis=0), x.max(axis=0)
    inner = np.all((x > lo + 0.6) & (x < hi - 0.6), axis=1)
    y = x + np.where(inner[:, None], rng.uniform(-amplitude, amplitude, x.shape), 0.0)
    return x, y, cells, inner


def _stars(y, cells, v):
    """Entries ``(p, face)`` of vertex ``v``'s star (faces oriented as the relaxation's)."""
    orient = np.sign(tet.signed_volumes(y, cells))
    ci, corner = np.nonzero(cells == v)
    f = cells[ci[:, None], tet.FACETS[corner]]
    neg = orient[ci] < 0
    f[neg] = f[neg][:, [0, 2, 1]]
    return tet.star_faces(y[f[:, 0]], y[f[:, 1]], y[f[:, 2]])


def test_ascent_direction_raises_a_unique_worst():
    """The weighted gradients' sum is an ascent direction of a star's worst quality where
    the worst entry is unique; a single entry's gradient matches finite differences."""
    x, y, cells, inner = _perturbed_a15(3)
    checked = 0
    for v in np.flatnonzero(inner)[::7]:
        face = _stars(y, cells, v)
        p = np.repeat(y[v][None], len(face.gx), axis=0)
        u, s, L = _star_data(p, face)
        q = tet.star_quality(p[:, 0], p[:, 1], p[:, 2], face)
        if q.min() <= 0:
            continue
        order = np.sort(q)
        qw = np.full_like(q, q.min())
        g = _dvr.ascent_gradients(q, qw, s, L, u, (face.nx, face.ny, face.nz))
        d = np.array([gi.sum() for gi in g])
        assert np.linalg.norm(d) > 0
        d /= np.linalg.norm(d)
        # Gradient of the worst entry against central differences.
        w = int(np.argmin(q))
        fw = face.select(np.array([w]))
        grad = np.empty(3)
        for i in range(3):
            e = np.zeros(3)
            e[i] = 1e-6
            qp = tet.star_quality(*(y[v] + e)[:, None], fw)[0]
            qm = tet.star_quality(*(y[v] - e)[:, None], fw)[0]
            grad[i] = (qp - qm) / 2e-6
        a, b = (2.0 / 3.0) / s[w], 2.0 / L[w]
        exact = q[w] * np.array([a * face.nx[w] - b * u[0][w], a * face.ny[w] - b * u[1][w],
                                 a * face.nz[w] - b * u[2][w]])  # fmt: skip
        assert np.allclose(exact, grad, rtol=1e-6, atol=1e-8)
        if order[1] - order[0] < 1e-3:
            continue  # a near tie: the worst is not unique at the step below
        checked += 1
        assert d @ exact > 0
        eps = 1e-6 * (order[1] - order[0])
        qe = tet.star_quality(*(y[v] + eps * d)[:, None], face)
        assert qe.min() > q.min()
    assert checked >= 10


def _relax(x, y, cells, movable, sweeps=None):
    n = len(x)
    return _dvr.relax_tetrahedra(
        MPI.COMM_SELF, _SerialMap(), lambda p: (p, np.zeros_like(p)), x, x.copy(), y, cells,
        movable, np.zeros(n, dtype=bool), np.zeros_like(x), np.zeros(n), np.ones(n),
        sweeps=sweeps,
    )  # fmt: skip


def _plane_relax(x, y, cells, movable, on_gamma, sweeps=None):
    """Vertices on the plane ``z = 1.5`` slide along it."""
    n = len(x)
    normal = np.tile([0.0, 0.0, 1.0], (n, 1))

    def closest_normal(p):
        q = p.copy()
        q[:, 2] = 1.5
        return q, np.tile([0.0, 0.0, 1.0], (len(p), 1))

    return _dvr.relax_tetrahedra(
        MPI.COMM_SELF, _SerialMap(), closest_normal, x, x.copy(), y, cells, movable,
        on_gamma, normal, np.zeros(n), np.ones(n), sweeps=sweeps,
    )  # fmt: skip


def _quality(y, cells, orient):
    q = tet.mean_ratio(y, cells) * orient
    return np.where(np.sign(tet.signed_volumes(y, cells)) == orient, q, -1.0)


@pytest.mark.parametrize("seed", [1, 2, 5])
@pytest.mark.parametrize("gamma", [False, True])
def test_relaxation_never_lowers_the_touched_stars(seed, gamma):
    """The worst tetrahedron of the moved vertices' stars never gets worse, none inverts,
    the fixed vertices stay and the vertices on Gamma stay on it; more sweeps never lower
    the overall worst quality."""
    x, y, cells, inner = _perturbed_a15(seed)
    on_gamma = np.zeros(len(x), dtype=bool)
    if gamma:
        near = inner & (np.abs(y[:, 2] - 1.5) < 0.15)
        y[near, 2] = 1.5
        on_gamma = near
    orient = np.sign(tet.signed_volumes(y, cells))
    assert np.all(orient > 0)
    q0 = _quality(y, cells, orient)
    history = [q0.min()]
    for sweeps in (1, 2, 6):
        r = (
            _plane_relax(x, y, cells, inner, on_gamma, sweeps)
            if gamma
            else _relax(x, y, cells, inner, sweeps)
        )
        assert r.num_moves > 0 and r.num_sweeps <= sweeps
        assert np.array_equal(r.y[~inner], y[~inner])
        assert np.array_equal(r.moved, np.any(r.y != x, axis=1))
        q = _quality(r.y, cells, orient)
        assert np.all(np.sign(tet.signed_volumes(r.y, cells)) == orient)
        touched = np.any(np.any(r.y != y, axis=1)[cells], axis=1)
        assert touched.any() and q[touched].min() >= q0[touched].min() - 1e-12
        history.append(q.min())
        if gamma:
            assert np.all(r.y[on_gamma, 2] == 1.5) and np.any(r.y[on_gamma] != y[on_gamma])
            slid = on_gamma & np.any(r.y != y, axis=1)
            assert np.array_equal(r.x[slid], r.y[slid])  # y + phi N, phi = 0
    assert all(b >= a - 1e-12 for a, b in zip(history, history[1:]))
    assert history[-1] > history[0] + 0.1


def test_relaxation_is_deterministic():
    x, y, cells, inner = _perturbed_a15(9)
    a, b = _relax(x, y, cells, inner), _relax(x, y.copy(), cells.copy(), inner.copy())
    assert np.array_equal(a.y, b.y) and np.array_equal(a.x, b.x)
    assert a.num_moves == b.num_moves and a.num_sweeps == b.num_sweeps
    # The order of the cells (and of their corners, keeping the orientation) changes
    # nothing but rounding.
    perm = np.random.default_rng(0).permutation(len(cells))
    c = _relax(x, y, cells[perm][:, [1, 2, 0, 3]], inner)
    assert np.abs(c.y - a.y).max() < 1e-12
    # Nor does their orientation: negatively oriented cells keep theirs.
    turned = cells.copy()
    turned[::2] = turned[::2][:, [1, 0, 2, 3]]
    d = _relax(x, y, turned, inner)
    assert np.abs(d.y - a.y).max() < 1e-12


def test_star_terms_match_star_faces():
    """The terms on separate coordinate arrays are those of star_faces / star_quality."""
    rng = np.random.default_rng(5)
    n = 3000
    p, a, b, c = _random_entries(rng, n)
    y = np.concatenate([p, a, b, c]) + 10.0  # off the origin: the centroid's rounding
    ip, ia, ib, ic = (np.arange(n) + i * n for i in range(4))
    yc = (y[:, 0].copy(), y[:, 1].copy(), y[:, 2].copy())
    u, nrm, lsq, s, L = _dvr.star_terms(yc, ip, ia, ib, ic)
    face = tet.star_faces(y[ia], y[ib], y[ic])
    scale = np.linalg.norm(np.stack([face.nx, face.ny, face.nz]), axis=0)
    for mine, ref in zip(nrm, (face.nx, face.ny, face.nz)):
        assert np.all(np.abs(mine - ref) <= 1e-12 * scale + 1e-300)
    assert np.allclose(lsq, face.lsq, rtol=1e-13, atol=0)
    q = np.where(s > 0, np.cbrt(s) ** 2 / L, -1.0)
    ref = tet.star_quality(y[ip, 0], y[ip, 1], y[ip, 2], face)
    clear = np.abs(s) > 1e-6 * np.sqrt(L) * scale
    assert clear.mean() > 0.6 and np.array_equal(q[clear] > -1, ref[clear] > -1)
    assert np.allclose(q[clear], ref[clear], rtol=1e-11, atol=0)


def test_vertex_colours_graph():
    """The colours of relax_common.vertex_colours (first fit in the same rounds), a proper
    colouring of the vertices of each cell; -1 corners are not coloured."""
    from dolfinx_universal.conforming.relax_common import (
        SubVertices,
        coordinate_priority,
        vertex_colours,
        vertex_colours_graph,
    )

    x, _, cells, inner = _perturbed_a15(4)
    local = np.full(len(x), -1)
    local[inner] = np.arange(int(inner.sum()))
    csub = local[cells]
    sub = SubVertices(_SerialMap(), np.flatnonzero(inner))
    pr = coordinate_priority(x[inner])
    colour = vertex_colours_graph(sub, csub, pr)
    assert np.array_equal(colour, vertex_colours(sub, csub, pr))
    assert colour.min() == 0
    for i in range(4):
        for j in range(i + 1, 4):
            both = (csub[:, i] >= 0) & (csub[:, j] >= 0)
            assert np.all(colour[csub[both, i]] != colour[csub[both, j]])


def test_compiled_colours_and_entries_are_numpy_s():
    """``dvr_colour`` gives the Jones-Plassmann colours of :func:`vertex_colours_graph`, and
    the star entries, their facets, orientations and ratings of the numpy set-up, bitwise:
    on perturbed A15 stars with turned (negatively oriented) cells, for two orders of the
    (distinct) priorities."""
    from dolfinx_universal.conforming.relax_common import (
        SubVertices,
        coordinate_priority,
        vertex_colours_graph,
    )
    from dolfinx_universal.core.compiled import relax_kernels

    kernels = relax_kernels()
    assert kernels is not None  # DOLFINx's C compiler (FFCx's) builds them
    x, y, cells, inner = _perturbed_a15(6, amplitude=0.3)
    cells = cells.copy()
    cells[::3] = cells[::3][:, [1, 0, 2, 3]]  # a third of the cells turned
    local = np.full(len(x), -1, dtype=np.int64)
    local[inner] = np.arange(int(inner.sum()))
    csub = local[cells]
    sub = SubVertices(_SerialMap(), np.flatnonzero(inner))
    for pr in (coordinate_priority(x[inner]), -coordinate_priority(x[inner])):
        colour, entries = _dvr._compiled_colours(kernels, csub, pr)
        ref = vertex_colours_graph(sub, csub, pr)
        np.testing.assert_array_equal(colour, ref)
        ncol = int(colour.max()) + 1
        verts, h = sub.vertices, np.ones(len(x))
        on_gamma = np.abs(y[:, 2] - 1.5) < 0.3
        a = _dvr._TetStars(y, cells, csub, colour, ncol, verts, on_gamma, h, kernels, entries)
        b = _dvr._TetStars(y, cells, csub, colour, ncol, verts, on_gamma, h)
        for name in ("cell_idx", "ev", "pv", "f0", "f1", "f2", "flat", "rcell", "cap_w"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        assert a.flat.any() is np.False_ and np.any(a.f1 != a.f0)


@pytest.mark.parametrize("frame", [False, True])
def test_compiled_relaxation_is_numpy_s(monkeypatch, frame):
    """The C visits (``dvr_visit``, ``dvr_slides``: ascent directions, line searches,
    compass, slides with capped edges of Gamma_h, early-out ratings) move the vertices
    exactly as the numpy visits do, bitwise: inside vertices of perturbed A15 patches and
    vertices sliding on a plane, with and without a turned frame."""
    from dolfinx_universal.conforming.relax_common import RelaxFrame
    from dolfinx_universal.core.compiled import relax_kernels

    assert relax_kernels() is not None
    angle = 0.4
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    fr = RelaxFrame(rot, np.array([0.1, 0.2, 0.3])) if frame else None

    def runs():
        out = []
        for seed in (1, 2):
            x, y, cells, inner = _perturbed_a15(seed, amplitude=0.3)
            near = inner & (np.abs(y[:, 2] - 1.5) < 0.15)
            y[near, 2] = 1.5
            n = len(x)

            def closest_normal(p):
                q = p.copy()
                q[:, 2] = 1.5
                return q, np.tile([0.0, 0.0, 1.0], (len(p), 1))

            r = _dvr.relax_tetrahedra(
                MPI.COMM_SELF, _SerialMap(), closest_normal, x, x.copy(), y, cells, inner,
                near, np.tile([0.0, 0.0, 1.0], (n, 1)), np.zeros(n), np.full(n, 0.5),
                frame=fr,
            )  # fmt: skip
            assert r.num_moves > 0
            out.append((r.y, r.x, r.num_moves, r.num_sweeps))
        return out

    compiled = runs()
    monkeypatch.setenv("DOLFINX_UNIVERSAL_COMPILED", "0")
    assert relax_kernels() is None
    for a, b in zip(compiled, runs(), strict=True):
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1], b[1])
        assert a[2:] == b[2:]


def test_compiled_moving_tetrahedra_are_numpy_s(monkeypatch):
    """Three steps of a moving ball and of a moving turned ellipsoid (the body's frame) on
    one A15 background, q = 2, of the ball at q = 3 and of a disc on triangles at q = 3: the
    same geometry, bitwise, with the C kernels (relaxation, affine nodes) and with the numpy
    code."""
    import dolfinx_universal as du
    from dolfinx_universal.core.compiled import relax_kernels

    comm = MPI.COMM_SELF
    bg = du.a15_mesh(comm, [[-1.2] * 3, [1.2] * 3], 0.16)
    ell = du.Ellipsoid([0.0, 0.0, 0.0], [0.75, 0.5, 0.4])

    def meshes():
        out = []
        md = du.MovingDomain(bg, degree=2, map="I~")
        for step in range(3):
            md.update(du.Sphere([0.03 * step, -0.02 * step, 0.01], 0.7))
            out.append(md.mesh.geometry.x.copy())
        md = du.MovingDomain(bg, degree=2, map="I~")
        for step in range(3):
            md.update(du.RigidMotion(ell, rotation=((0.3, 0.2, 1.0), 0.2 * step + 0.1)))
            out.append(md.mesh.geometry.x.copy())
        md = du.MovingDomain(bg, degree=3, map="I")  # face nodes: sums of three terms
        for step in range(3):
            md.update(du.Sphere([-0.02 * step, 0.03 * step, 0.01], 0.6))
            out.append(md.mesh.geometry.x.copy())
        md = du.MovingDomain(du.equilateral_mesh(comm, [[0, 0], [1, 1]], 0.04), degree=3)
        for step in range(3):
            md.update(du.Circle([0.5 + 0.011 * step, 0.49], 0.3))
            out.append(md.mesh.geometry.x.copy())
        return out

    assert relax_kernels() is not None
    compiled = meshes()
    monkeypatch.setenv("DOLFINX_UNIVERSAL_COMPILED", "0")
    assert relax_kernels() is None
    for a, b in zip(compiled, meshes(), strict=True):
        np.testing.assert_array_equal(a, b)
