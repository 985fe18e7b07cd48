"""Tetrahedron geometry and quality on vertex arrays: the 3D counterparts of ``_geometry``.

Every function on cells takes vertex coordinates ``x`` ``(num_vertices, 3)`` and
tetrahedra ``cells`` ``(m, 4)`` of vertex indices. A tetrahedron ``(v0, v1, v2, v3)`` is
*positively oriented* when ``det[x1 - x0, x2 - x0, x3 - x0] > 0``, as DOLFINx's (basix's)
reference tetrahedron ``(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)`` is.

Local numbering follows basix: edge ``e`` joins the vertices :data:`EDGES` ``[e]`` =
``(2, 3), (1, 3), (1, 2), (0, 3), (0, 2), (0, 1)`` (edge ``5 - e`` is the opposite one) and
facet ``k`` is the face opposite vertex ``k``. :data:`FACETS` orders each facet's vertices
so that its right-hand-rule normal points out of a positively oriented tetrahedron;
equivalently, ``(vk, a, b, c)`` is an even permutation of ``(v0, v1, v2, v3)`` for facet
``k = (a, b, c)``, so the tetrahedron ``(p, a, b, c)`` is positively oriented while ``p``
(the vertex ``k`` moved) stays on the inner side of the facet: the star entries of the
vertex relaxation (:func:`star_entries`, :func:`star_faces`, :func:`star_quality`).

Quality measures, each 1 for the regular tetrahedron:

- the *mean ratio* ``12 (3 |V|)^(2/3) / sum of squared edge lengths`` (Liu & Joe 1994;
  Knupp 2001), signed here by the orientation (the relaxation's objective: it stays
  smooth through inversion);
- the *radius ratio* ``3 r_in / R_circ`` in ``[0, 1]``;
- the dihedral angles (``arccos(1/3)`` = 70.53 degrees for the regular tetrahedron).

The compass directions of the relaxation in 3D (:func:`directions` on the sphere,
:func:`tangent_directions` in tangent planes) change from sweep to sweep deterministically,
as the 2D compass turns by the golden angle.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from dolfinx_universal.core.arrays import Float, Int

__all__ = [
    "barycentric",
    "DIHEDRAL_BIN_EDGES",
    "EDGES",
    "FACETS",
    "TARGET_MEAN_RATIO",
    "StarFaces",
    "cell_diameters",
    "dihedral_angles",
    "directions",
    "edge_lengths",
    "facets",
    "mean_ratio",
    "quality_summary",
    "radius_ratio",
    "signed_volumes",
    "soa_corners",
    "soa_cross",
    "soa_det6",
    "soa_dihedral",
    "soa_dot",
    "soa_sq",
    "soa_sub",
    "star_entries",
    "star_faces",
    "star_quality",
    "star_volume_terms",
    "summary_and_volumes",
    "tangent_angles",
    "tangent_directions",
]

EDGES = np.array([[2, 3], [1, 3], [1, 2], [0, 3], [0, 2], [0, 1]], dtype=np.int64)
"""Local vertices of the 6 edges (basix's numbering), ``(6, 2)``; edge ``5 - e`` is
opposite edge ``e``."""
FACETS = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)
"""Local vertices of the facet opposite each vertex, ``(4, 3)``: basix's facet ``k`` (the
same vertex set), ordered so that the normal ``(b - a) x (c - a)`` of facet ``(a, b, c)``
points out of a positively oriented tetrahedron (``(k, a, b, c)`` is an even permutation
of ``(0, 1, 2, 3)``)."""
DIHEDRAL_BIN_EDGES = np.linspace(0.0, 180.0, 19)
"""Edges (degrees) of the dihedral angle histogram of :func:`quality_summary`: 18 bins of
10 degrees (the last one closed: 180 counts in it)."""
TARGET_MEAN_RATIO = 0.85
"""Mean ratio at which :func:`star_quality` is 1. The regular tetrahedron has 1, the BCC
lattice's 0.952 and the A15 lattice's 0.945-0.991; after snapping and relaxation the worst
tetrahedra of the 3D prototype reached 0.75-0.83 (target: at least 0.7), and it stopped
moving vertices whose tetrahedra were all above 0.9, which is about what a 5 % margin
above this target gives (the 2D relaxation's ``ACTIVE_BELOW = 1.05``)."""

_GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))
# Roberts' generalised golden ratio for 3 dimensions (the real root of x^4 = x + 1): the
# additive recurrence frac(1/2 + s (1/g, 1/g^2, 1/g^3)) is a low-discrepancy sequence of
# the unit cube, mapped to rotations by Shoemake's uniform map.
_G3 = 1.2207440846057596
_KRONECKER3 = np.array([1.0 / _G3, 1.0 / _G3**2, 1.0 / _G3**3])


def _cross(u: Float, v: Float) -> Float:
    """Cross products along the last axis (``np.cross`` without its overhead)."""
    return np.stack(
        [
            u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1],
            u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
            u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0],
        ],
        axis=-1,
    )


def _sq(v: Float) -> Float:
    """Squared norms along the last axis."""
    return v[..., 0] ** 2 + v[..., 1] ** 2 + v[..., 2] ** 2


def signed_volumes(x: Float, cells: Int) -> Float:
    """Signed volumes ``det[x1 - x0, x2 - x0, x3 - x0] / 6``, shape ``(m,)``.

    Positive for tetrahedra oriented as the reference tetrahedron.
    """
    return soa_det6(soa_corners(x, cells)) / 6.0


def edge_lengths(x: Float, cells: Int) -> Float:
    """Edge lengths of tetrahedra, shape ``(m, 6)``.

    Column ``e`` is the length of edge :data:`EDGES` ``[e]``, i.e. of the local vertex pairs
    ``(2, 3), (1, 3), (1, 2), (0, 3), (0, 2), (0, 1)`` (basix's edge numbering).
    """
    p = soa_corners(x, cells)
    return np.column_stack([np.sqrt(soa_sq(soa_sub(p[j], p[i]))) for i, j in EDGES])


def cell_diameters(x: Float, cells: Int) -> Float:
    """Longest edge of each tetrahedron, shape ``(m,)``."""
    return edge_lengths(x, cells).max(axis=1)


def soa_cross(u: list[Float], v: list[Float]) -> list[Float]:
    """Cross products of vectors given as their 3 component arrays."""
    return [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ]


def soa_dot(u: list[Float], v: list[Float]) -> Float:
    """Dot products of vectors given as their 3 component arrays."""
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def soa_sub(u: list[Float], v: list[Float]) -> list[Float]:
    """Differences of vectors given as their 3 component arrays."""
    return [u[0] - v[0], u[1] - v[1], u[2] - v[2]]


def soa_sq(u: list[Float]) -> Float:
    """Squared norms of vectors given as their 3 component arrays."""
    return u[0] ** 2 + u[1] ** 2 + u[2] ** 2


def soa_det6(p: list[list[Float]]) -> Float:
    """``6 V`` of tetrahedra with corners ``p[vertex][coordinate]`` ``(m,)``."""
    d = [soa_sub(p[k], p[0]) for k in (1, 2, 3)]
    return soa_dot(d[0], soa_cross(d[1], d[2]))


def soa_corners(x: Float, cells: Int) -> list[list[Float]]:
    """Corners of tetrahedra as ``p[vertex][coordinate]`` arrays ``(m,)``, each gathered
    from a coordinate column: the arithmetic on these contiguous arrays takes about half
    the time it takes on the strided columns of an ``(m, 4, 3)`` gather."""
    x = np.asarray(x, dtype=np.float64)
    cells = np.asarray(cells)
    cols = [np.ascontiguousarray(cells[:, k]) for k in range(4)]
    return [[x[:, i][c] for i in range(3)] for c in cols]


def _soa_normals(p: list[list[Float]]) -> list[list[Float]]:
    """Area normals ``(b - a) x (c - a)`` of the facets :data:`FACETS` of corners ``p``."""
    return [soa_cross(soa_sub(p[b], p[a]), soa_sub(p[c], p[a])) for a, b, c in FACETS]


def _soa_edges_sq(p: list[list[Float]]) -> list[Float]:
    """Squared lengths of the edges :data:`EDGES` of corners ``p``."""
    return [soa_sq(soa_sub(p[j], p[i])) for i, j in EDGES]


def soa_dihedral(
    p: list[list[Float]],
    v6: Float,
    n: list[list[Float]] | None = None,
    edges_sq: list[Float] | None = None,
) -> Float:
    """:func:`dihedral_angles` of corners ``p`` (:func:`soa_corners`) with ``6 V`` ``v6``
    (and the facet normals and squared edge lengths, if already computed)."""
    n = _soa_normals(p) if n is None else n
    edges_sq = _soa_edges_sq(p) if edges_sq is None else edges_sq
    av6 = np.abs(v6)
    angles = np.empty((len(av6), 6))
    for e, (k, m) in enumerate(EDGES[::-1]):
        nk, nl = n[k], n[m]
        theta = np.arctan2(av6 * np.sqrt(edges_sq[e]), -soa_dot(nk, nl))
        undefined = (soa_sq(nk) == 0.0) | (soa_sq(nl) == 0.0)
        angles[:, e] = np.where(undefined, np.nan, theta)
    return angles


def dihedral_angles(x: Float, cells: Int) -> Float:
    """Interior dihedral angle (radians) at each edge of each tetrahedron, shape ``(m, 6)``.

    Column ``e`` is the angle at edge :data:`EDGES` ``[e]``: between the two facets through
    it, measured inside the tetrahedron (in ``[0, pi]``). It depends on the tetrahedron's
    shape only, not on its orientation, so inverted tetrahedra get their geometric angles.
    With ``N_k``, ``N_l`` the area normals of the facets opposite the other two vertices
    ``k``, ``l`` (both outward or both inward), ``|N_k| |N_l| cos(theta) = -N_k . N_l`` and
    ``|N_k| |N_l| sin(theta) = 6 |V| |e|``, and ``theta = atan2(6 |V| |e|, -N_k . N_l)``,
    accurate near 0 and pi too.

    Flat tetrahedra (``V = 0``) with facets of positive area get angles of exactly 0 or
    pi. The angle at an edge with a facet of zero area (a collapsed edge or collinear
    corners: the facet's plane is undefined) is ``nan``.
    """
    p = soa_corners(x, cells)
    return soa_dihedral(p, soa_det6(p))


def _mean_ratio(v6: Float, lsum: Float) -> Float:
    """Signed mean ratio from ``6 V`` and the sum of squared edge lengths (0 if both 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.sign(v6) * 12.0 * np.cbrt(0.5 * np.abs(v6)) ** 2 / lsum
    return np.where(lsum > 0.0, q, 0.0)


def mean_ratio(x: Float, cells: Int) -> Float:
    """Signed mean ratio of tetrahedra, shape ``(m,)``.

    ``sign(V) 12 (3 |V|)^(2/3) / sum_e l_e^2`` (``V`` the signed volume, ``l_e`` the 6 edge
    lengths): 1 for the regular tetrahedron, in ``(0, 1]`` for positively oriented ones,
    ``[-1, 0)`` for inverted ones (``abs`` gives the usual unsigned mean ratio) and 0 for
    flat ones. It equals ``3 det(S)^(2/3) / |S|_F^2`` of the map ``S`` from the regular
    tetrahedron (Knupp 2001).
    """
    p = soa_corners(x, cells)
    return _mean_ratio(soa_det6(p), _lsum(_soa_edges_sq(p)))


def _lsum(edges_sq: list[Float]) -> Float:
    """Sum of the squared edge lengths (in the order :data:`EDGES`)."""
    lsum = np.zeros(len(edges_sq[0]))
    for sq in edges_sq:
        lsum += sq
    return lsum


def radius_ratio(x: Float, cells: Int) -> Float:
    """Normalised radius ratio ``3 r_in / R_circ`` of tetrahedra, shape ``(m,)``.

    In ``[0, 1]``: 1 for the regular tetrahedron, 0 for flat ones; independent of the
    orientation. With ``d_i = x_i - x_0`` and ``D = d_1 . (d_2 x d_3) = 6 V``, the
    circumcentre is ``x_0 + N / (2 D)`` where ``N = |d_1|^2 d_2 x d_3 + |d_2|^2 d_3 x d_1
    + |d_3|^2 d_1 x d_2``, and ``r_in = 3 |V| / S`` (``S`` the total facet area), so the
    ratio is ``108 V^2 / (S |N|)``.
    """
    p = soa_corners(x, cells)
    return _soa_radius_ratio(soa_det6(p), _soa_normals(p), _soa_edges_sq(p))


def _soa_radius_ratio(v6: Float, n: list[list[Float]], edges_sq: list[Float]) -> Float:
    """:func:`radius_ratio` from ``6 V``, the facet normals and the squared edge lengths.

    With ``d_k = x_k - x_0``, the facets through vertex 0 have the normals ``-d_2 x d_3``,
    ``-d_3 x d_1`` and ``-d_1 x d_2`` (facets 1, 2, 3), so ``-N`` is
    ``|d_1|^2 n_1 + |d_2|^2 n_2 + |d_3|^2 n_3`` (exactly: rounding is odd).
    """
    s1, s2, s3 = edges_sq[5], edges_sq[4], edges_sq[3]  # |d_1|^2, |d_2|^2, |d_3|^2
    big_n = [s1 * n[1][i] + s2 * n[2][i] + s3 * n[3][i] for i in range(3)]
    area = np.zeros(len(v6))
    for nk in n:
        area += np.sqrt(soa_sq(nk))
    area *= 0.5
    den = area * np.sqrt(soa_sq(big_n))
    with np.errstate(divide="ignore", invalid="ignore"):
        q = 3.0 * v6 * v6 / den  # 108 V^2 = 3 (6 V)^2
    return np.where(den > 0.0, q, 0.0)


def _orientation_flip(orientation: Float | None, m: int) -> npt.NDArray[np.bool_]:
    """Cells whose facets are reversed: those with ``orientation < 0``."""
    if orientation is None:
        return np.zeros(m, dtype=bool)
    flip = np.asarray(orientation) < 0
    if flip.shape != (m,):
        raise ValueError(f"orientation must have shape ({m},), not {flip.shape}")
    return flip


def facets(cells: Int, orientation: Float | None = None) -> Int:
    """Facets of tetrahedra, outward, shape ``(m, 4, 3)``.

    ``facets(cells)[i, k]`` is the facet of cell ``i`` opposite its local vertex ``k``
    (basix's facet ``k``), in the order :data:`FACETS`: for a positively oriented cell,
    its normal ``(b - a) x (c - a)`` points out of the cell. The boundary facets of a set of
    positively oriented cells, taken from here, are the outward-oriented boundary.

    Parameters
    ----------
    cells
        Tetrahedra ``(m, 4)``.
    orientation
        Optional signs ``(m,)`` of the cells' volumes: cells with a negative sign get their
        facets reversed (last two vertices swapped), so that every facet with
        ``orientation * V > 0`` points outward.
    """
    f = cells[:, FACETS]  # a copy (advanced indexing)
    flip = _orientation_flip(orientation, len(f))
    f[flip] = f[flip][:, :, [0, 2, 1]]
    return f


def star_entries(cells: Int, orientation: Float | None = None) -> tuple[Int, Int]:
    """The star entries of the vertex relaxation: each corner with its opposite facet.

    For corner ``k`` of cell ``i``: the moving vertex ``cells[i, k]`` and its opposite
    facet ``(a, b, c)`` ordered so that ``(vertex, a, b, c)`` is positively oriented when
    the cell is (``orientation * V > 0``): its quality is then
    ``star_quality(vertex position, star_faces(a, b, c))``. The order is that of
    :func:`facets`.

    Parameters
    ----------
    cells
        Tetrahedra ``(m, 4)``.
    orientation
        Optional signs ``(m,)`` the cells' volumes must have (default all positive).

    Returns
    -------
    The moving vertices ``(m, 4)`` (``cells`` itself) and their facets ``(m, 4, 3)``.
    """
    return cells, facets(cells, orientation)


class StarFaces(NamedTuple):
    """Per-entry data of fixed facets ``(a, b, c)`` for :func:`star_quality`.

    Each field has the shape of the entries, ``(...)``; with the 6V and mean-ratio
    scalings folded in, so that a candidate costs one dot product and one squared norm.
    """

    gx: Float
    """Centroid ``g = (a + b + c) / 3``, x."""
    gy: Float
    """Centroid, y."""
    gz: Float
    """Centroid, z."""
    nx: Float
    """``-k^(3/2) (b - a) x (c - a)``, x (``k = 4 * 2^(-2/3) / target``)."""
    ny: Float
    """As ``nx``, y."""
    nz: Float
    """As ``nx``, z."""
    lsq: Float
    """``4/9`` of the sum of the squared edge lengths of the facet (at least the smallest
    normal float, so that the kernel never divides 0 by 0)."""

    def select(self, entries: Int | slice, trailing: int = 0) -> StarFaces:
        """The entries ``entries`` (an index into the first axis), with ``trailing`` unit axes
        appended to each field (to broadcast against candidates ``(len(entries), ...)``)."""
        add = (slice(None),) + (None,) * trailing
        return StarFaces(*(v[entries][add] for v in self))


def star_faces(a: Float, b: Float, c: Float, *, target: float = TARGET_MEAN_RATIO) -> StarFaces:
    """Precompute the candidate-independent part of :func:`star_quality` for facets.

    Parameters
    ----------
    a, b, c
        Facet corners ``(..., 3)`` (broadcast together), ordered so that ``(p, a, b, c)``
        is positively oriented for valid positions ``p`` (as :func:`star_entries` gives).
    target
        Mean ratio at which the quality is 1.

    Returns
    -------
    The per-entry arrays, shape ``(...)``.
    """
    a, b, c = (np.asarray(v, dtype=np.float64) for v in (a, b, c))
    g = (a + b + c) / 3.0
    ab, ac, bc = b - a, c - a, c - b
    k = 4.0 * 2.0 ** (-2.0 / 3.0) / target
    n = _cross(ab, ac) * -(k**1.5)
    f = _sq(ab) + _sq(ac) + _sq(bc)
    lsq = np.maximum(f * (4.0 / 9.0), np.finfo(np.float64).tiny)  # > 0: no 0 / 0
    return StarFaces(g[..., 0], g[..., 1], g[..., 2], n[..., 0], n[..., 1], n[..., 2], lsq)


def star_quality(
    px: Float, py: Float, pz: Float, face: StarFaces, *, signed: bool = False
) -> Float:
    """Signed mean ratio / target of tetrahedra ``(p, a, b, c)``; -1 where ``V <= 0``.

    The kernel of the 3D vertex relaxation: candidate positions ``p`` of a moving vertex
    against the fixed facets ``(a, b, c)`` of :func:`star_faces` (positively oriented
    when valid). With ``g`` the facet's centroid, ``q = p - g`` and ``n = (b - a) x (c - a)``:
    ``6 V = (a - p) . n = -q . n`` (``(a - g) . n = 0``) and the sum of the squared edge
    lengths is ``3 |q|^2 + 4/3 F`` (``F`` that of the facet), so the mean ratio over the
    target is ``cbrt(s)^2 / (|q|^2 + 4/9 F)`` with ``s = -k^(3/2) q . n = k^(3/2) 6 V``,
    ``k = 4 * 2^(-2/3) / target``. Working relative to ``g`` keeps the cancellation to the
    cell's scale (relative error about ``eps |g| / height of p above the facet``).

    Cost: 21 array passes of the candidates' shape, 4 of them on booleans (3 subtractions,
    5 for ``s``, 6 for the norm: :func:`star_volume_terms`; cube root, square, division,
    and a branch-free blend to -1 where ``s <= 0``: masked assignments cost 2-3 times more
    when the invalid candidates are scattered); with ``signed``, 18. Five float
    temporaries.

    Parameters
    ----------
    px, py, pz
        Candidate coordinates, all of one shape, broadcast against the fields of ``face``.
        Fields with fewer axes get trailing unit axes: fields ``(ne,)`` (entries) against
        candidates ``(ne, nc)``. The 7 passes that read a field take about half as long
        with the candidates laid out ``(nc, ne)`` against fields ``(1, ne)``
        (``StarFaces(*(v[None] for v in face))``): numpy's inner loops are then long.
    face
        The facets, from :func:`star_faces`.
    signed
        Return the signed mean ratio / target (negative where inverted, 0 where flat)
        instead of -1 where ``V <= 0``: an objective that can untangle.

    Returns
    -------
    The qualities, shape of the broadcast inputs.
    """
    s, L = star_volume_terms(px, py, pz, face)
    r = np.cbrt(s)
    if signed:
        r *= np.abs(r)
        r /= L
        return r
    r *= r
    r /= L
    mask = np.greater(s, 0.0)
    r *= mask
    np.less_equal(s, 0.0, out=mask)
    r -= mask  # r where s > 0, 0 - 1 elsewhere
    return r


def star_volume_terms(px: Float, py: Float, pz: Float, face: StarFaces) -> tuple[Float, Float]:
    """``s = k^(3/2) 6 V`` and ``L`` (the sum of the squared edge lengths over 3) of the
    tetrahedra ``(p, a, b, c)`` of :func:`star_quality` (same arguments), whose quality is
    ``cbrt(s)^2 / L``: 13 array passes, four float temporaries."""
    nd = np.ndim(px)
    gx, gy, gz, nx, ny, nz, lsq = (
        v.reshape(v.shape + (1,) * (nd - v.ndim)) if v.ndim < nd else v for v in face
    )
    qx, qy, qz = px - gx, py - gy, pz - gz
    s = qx * nx
    t = qy * ny
    s += t
    np.multiply(qz, nz, out=t)
    s += t  # k^(3/2) 6 V
    np.multiply(qx, qx, out=qx)
    np.multiply(qy, qy, out=qy)
    qx += qy
    np.multiply(qz, qz, out=qz)
    qx += qz
    qx += lsq  # (sum of squared edge lengths) / 3 > 0
    return s, qx


def quality_summary(
    x: Float, cells: Int, orientation: Float | None = None
) -> dict[str, float | int | npt.NDArray[np.int64]]:
    """Quality figures of tetrahedra (process-local; the caller reduces over ranks).

    Parameters
    ----------
    x
        Vertex coordinates ``(num_vertices, 3)``.
    cells
        Tetrahedra ``(m, 4)``.
    orientation
        Optional signs ``(m,)`` the volumes should have (e.g. those in the background
        mesh; default all positive): a cell is inverted where ``orientation * V <= 0`` and
        its mean ratio is signed accordingly.

    Returns
    -------
    A dict with ``n_cells``; ``dihedral_min_deg`` and ``dihedral_max_deg`` (over the defined
    angles; 180 and 0 when there are none), ``dihedral_histogram`` (counts ``(18,)`` of the
    defined angles in the 10-degree bins :data:`DIHEDRAL_BIN_EDGES`: reduce by summing);
    ``radius_ratio_min`` and ``mean_ratio_min`` (signed; both 1 when there are no cells);
    ``n_inverted`` (``orientation * V <= 0``, flat cells included) and ``n_degenerate``
    (cells with an undefined dihedral angle: a facet of zero area).
    """
    return summary_and_volumes(x, cells, orientation)[0]


def summary_and_volumes(
    x: Float, cells: Int, orientation: Float | None = None
) -> tuple[dict[str, float | int | npt.NDArray[np.int64]], Float]:
    """:func:`quality_summary` and the :func:`signed_volumes` ``(m,)`` it computes on the way."""
    m = len(cells)
    flip = _orientation_flip(orientation, m)
    sign = np.where(flip, -1.0, 1.0)
    # The corners, 6 V, facet normals and edge lengths once, for all the figures.
    p = soa_corners(x, cells)
    v6 = soa_det6(p)
    n, edges_sq = _soa_normals(p), _soa_edges_sq(p)
    ang = np.degrees(soa_dihedral(p, v6, n, edges_sq))
    defined = ang[np.isfinite(ang)]
    hist, _ = np.histogram(defined, bins=DIHEDRAL_BIN_EDGES)
    mr = sign * _mean_ratio(v6, _lsum(edges_sq))
    rr = _soa_radius_ratio(v6, n, edges_sq)
    volumes = v6 / 6.0
    summary: dict[str, float | int | npt.NDArray[np.int64]] = {
        "n_cells": m,
        "dihedral_min_deg": float(defined.min()) if len(defined) else 180.0,
        "dihedral_max_deg": float(defined.max()) if len(defined) else 0.0,
        "dihedral_histogram": hist.astype(np.int64),
        "radius_ratio_min": float(rr.min()) if m else 1.0,
        "mean_ratio_min": float(mr.min()) if m else 1.0,
        "n_inverted": int(np.count_nonzero(sign * volumes <= 0.0)),
        "n_degenerate": int(np.count_nonzero(np.isnan(ang).any(axis=1))),
    }
    return summary, volumes


def _fibonacci_sphere(n: int) -> Float:
    """``n`` points of the Fibonacci (golden spiral) lattice on the unit sphere, ``(n, 3)``."""
    i = np.arange(n, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / n
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    theta = i * _GOLDEN_ANGLE
    return np.column_stack([r * np.cos(theta), r * np.sin(theta), z])


def _sweep_rotation(sweep: int) -> Float:
    """Rotation matrix ``(3, 3)`` of a sweep: quasi-random and well spread over sweeps.

    The ``sweep``-th point of the 3D Kronecker sequence (Roberts' generalised golden ratio)
    mapped to a rotation by Shoemake's uniform map (unit quaternions).
    """
    u1, u2, u3 = np.mod(0.5 + sweep * _KRONECKER3, 1.0)
    a, b = np.sqrt(1.0 - u1), np.sqrt(u1)
    qx, qy = a * np.sin(2.0 * np.pi * u2), a * np.cos(2.0 * np.pi * u2)
    qz, qw = b * np.sin(2.0 * np.pi * u3), b * np.cos(2.0 * np.pi * u3)
    return np.array(
        [
            [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
            [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
            [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
        ]
    )


def directions(n: int, sweep: int) -> Float:
    """``n`` well-spread unit directions in 3D for a sweep of the compass search, ``(n, 3)``.

    The Fibonacci sphere of ``n`` points, turned by a rotation that changes from sweep to
    sweep (the ``sweep``-th of a low-discrepancy sequence of rotations), as the 2D compass
    turns by the golden angle: over the sweeps, the directions tried cover the sphere.
    Deterministic: the same ``(n, sweep)`` give the same directions.
    """
    return _fibonacci_sphere(n) @ _sweep_rotation(sweep).T


def tangent_directions(normal: Float, n: int, sweep: int) -> Float:
    """``n`` unit directions in the tangent plane of each normal, shape ``(k, n, 3)``.

    Direction ``j`` is ``cos(theta_j) t1 + sin(theta_j) t2`` with
    ``theta_j = sweep * golden angle + 2 pi j / n`` and ``(t1, t2)`` an orthonormal basis of
    the plane: ``t1`` is the coordinate axis least aligned with the normal, made orthogonal
    to it, and ``t2 = normal x t1`` (so ``(t1, t2, normal)`` is right-handed).

    Parameters
    ----------
    normal
        Normals ``(k, 3)`` (nonzero; they need not be unit).
    n
        Directions per plane.
    sweep
        Sweep number: the directions turn by the golden angle per sweep.
    """
    nrm = np.asarray(normal, dtype=np.float64)
    nrm = nrm / np.sqrt(_sq(nrm))[:, None]
    rows = np.arange(len(nrm))
    axis = np.argmin(np.abs(nrm), axis=1)
    t1 = -nrm[rows, axis][:, None] * nrm
    t1[rows, axis] += 1.0  # e - (e . n) n, |e . n| <= 1/sqrt(3)
    t1 /= np.sqrt(_sq(t1))[:, None]
    t2 = _cross(nrm, t1)
    theta = tangent_angles(n, sweep)
    return np.cos(theta)[None, :, None] * t1[:, None] + np.sin(theta)[None, :, None] * t2[:, None]


def tangent_angles(n: int, sweep: int) -> Float:
    """The angles ``theta_j`` of :func:`tangent_directions` ``(n,)``."""
    return sweep * _GOLDEN_ANGLE + 2.0 * np.pi * np.arange(n) / n


def barycentric(x: Float, cells: Int, p: Float) -> Float:
    """Barycentric coordinates of vertices 1, 2 and 3 of tetrahedra ``cells[i]`` at points
    ``p[i]`` ``(m, 3)`` (-inf where a tetrahedron is degenerate)."""
    # Cramer's rule on coordinate columns (np.linalg on (k, 3, 3) is slower)
    xt = [x[:, i] for i in range(3)]
    av = [xt[i][cells[:, 0]] for i in range(3)]
    e1, e2, e3 = ([xt[i][cells[:, k]] - av[i] for i in range(3)] for k in (1, 2, 3))
    pa = [p[:, i] - av[i] for i in range(3)]
    n1, n2, n3 = soa_cross(e2, e3), soa_cross(e3, e1), soa_cross(e1, e2)
    det = soa_dot(e1, n1)
    ok_det = np.abs(det) > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.column_stack([soa_dot(pa, n) / det for n in (n1, n2, n3)])
    lam[~ok_det] = -np.inf
    return lam
