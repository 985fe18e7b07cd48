"""Mesh sizes: from the geometry (local feature size, graded size fields) and from the user
(distance thresholds, boxes, and the marked cells of an adaptive loop)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.spatial import Delaunay, QhullError, cKDTree

from dolfinx_universal.backgrounds.lattice_tri import largest_of_cells
from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.cells.kit import cell_kernels
from dolfinx_universal.core.arrays import (
    Bool,
    Float,
    Int,
    as_box,
    as_points,
    cross2,
    kd_query,
    norm2,
    positive,
    readonly,
)
from dolfinx_universal.core.collective import collective_call, raise_collective
from dolfinx_universal.sizing.gaps import narrow_gap

__all__ = [
    "FEATURE_DIVISOR",
    "CurveSamples",
    "MinSize",
    "SizeField",
    "SizeFunction",
    "box_size",
    "curve_samples",
    "feature_divisor",
    "feature_size",
    "mark_cells",
    "medial_radius",
    "refine_size",
    "size_field",
    "target_sizes",
    "threshold",
]


FEATURE_DIVISOR: dict[int, float] = {1: 3.0, 2: 3.0, 3: 4.0}
"""Default ratio ``c(degree)`` of the local feature size to the target mesh size near Gamma,
by geometry degree (degrees above the largest key use the largest key's value). Tunable."""

RESOLUTION = 16.0
"""Samples per smallest feature that :func:`feature_size` aims for (spacing = feature / 16)."""

MIN_RESOLUTION = 4.0
"""Fewest samples per feature that :func:`feature_size` accepts; below it raises."""

MAX_SAMPLES = 2**18
"""Default sampling budget of :func:`feature_size` (all curves together)."""

_INITIAL_CELLS = 1024  # first spacing of feature_size: bounding-box diagonal / 1024
_NOISE = 1e-12  # |(q - p).n| below this fraction of |q - p|: q is on the tangent line of p
_JITTER = 1e-7  # jitter of the samples for the triangulation, relative to their spacing
_WINDOW = 4  # neighbours along the curve (each way) always tested by medial_radius
_GRID_CELLS = 256  # cells of the distance lower-bound grids of a size field (longer side)


# ----------------------------------------------------------------------------- helpers
def _points(x: npt.ArrayLike, name: str) -> Float:
    """``x`` as a finite float64 array ``(n, 2)``; a flat empty array is ``(0, 2)``."""
    a = np.asarray(x, dtype=np.float64)
    return as_points(a.reshape(0, 2) if a.ndim == 1 and a.size == 0 else a, name)


def _at(p: Float) -> str:
    return f"({p[0]:.6g}, {p[1]:.6g})"


# ----------------------------------------------------------------------------- samples
@dataclass(frozen=True, eq=False)
class CurveSamples:
    """Dense ordered samples of every closed curve of Gamma, with normals and topology.

    The samples of curve ``k`` are ``points[offsets[k]:offsets[k + 1]]``, in order along it
    (closed: the last one is followed by the first). Arrays are read-only.
    """

    points: Float
    """Points of Gamma ``(n, 2)``."""
    normals: Float
    """Unit outward normals of Omega there ``(n, 2)`` (for a Domain: into the bodies)."""
    labels: Int
    """Curve of each sample ``(n,)``, in ``0 .. num_curves - 1``."""
    offsets: Int
    """Start of each curve's samples, and ``n``: ``(num_curves + 1,)``."""
    num_curves: int
    """Number of closed curves of Gamma."""
    encloses_domain: Bool
    """``(num_curves,)``: whether Omega lies inside the curve next to it (the curve is the
    outer boundary of a piece of Omega)."""
    expected_pieces: int
    """Connected pieces of Omega within a box containing Gamma: the curves that enclose the
    domain, plus one if the far field lies in Omega."""
    spacing: float
    """Largest distance between consecutive samples of a curve."""


def _next(offsets: Int) -> tuple[Int, Int]:
    """Previous and next sample along its curve, for every sample, ``(n,)`` each."""
    n = np.diff(offsets)
    start, size = np.repeat(offsets[:-1], n), np.repeat(n, n)
    i = np.arange(offsets[-1]) - start
    return start + (i - 1) % size, start + (i + 1) % size


def curve_samples(boundary: Boundary, spacing: float) -> CurveSamples:
    """Ordered samples of every closed curve of ``boundary`` at most ``spacing`` apart.

    The loops are ``boundary.loops(spacing)``; normals are ``boundary.normal(points)``
    (from the curve parameters where the boundary knows them: no projection).
    A curve encloses the domain when a point just inside Omega next to it (``p - eps n``,
    ``eps -> 0``) lies inside the curve's polygon: for a simple closed curve this holds when
    the inward direction ``-n`` is on the interior side of the polygon, i.e. on the left of
    its tangent for a counter-clockwise polygon (positive signed area). The test is a vote
    over all samples of the curve (no ``eps`` to choose). The far field is in Omega when
    ``boundary.sign`` is -1 at a point one bounding-box diagonal outside the box.

    Parameters
    ----------
    boundary
        The boundary Gamma.
    spacing
        Largest distance between consecutive samples ``> 0``.

    Returns
    -------
    The samples, normals, curve labels and topology of Gamma.

    Raises
    ------
    ValueError
        Bad ``spacing``, no curve, or normals that do not point to one side of a curve
        (overlapping components, a curve crossing itself).
    """
    spacing = positive(spacing, "spacing")
    raw, raw_normals = boundary.loops_normals(spacing)
    keep = [k for k, q in enumerate(raw) if len(q) >= 3]
    loops = [np.asarray(raw[k], dtype=np.float64)[:, :2] for k in keep]
    if not loops:
        raise ValueError(f"{type(boundary).__name__} has no closed curve to sample")
    lengths = np.array([len(q) for q in loops], dtype=np.intp)
    ncurves = len(loops)
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.intp)
    pts = np.ascontiguousarray(np.concatenate(loops))
    if not np.isfinite(pts).all():
        raise ValueError("the samples of the boundary are not finite")
    normals = np.concatenate([np.asarray(raw_normals[k], dtype=np.float64) for k in keep])
    labels = np.repeat(np.arange(ncurves, dtype=np.intp), lengths)
    prev, nxt = _next(offsets)
    # Orientation of each loop (shoelace about its mean, for accuracy) and the side of -n.
    centred = pts - (np.add.reduceat(pts, offsets[:-1]) / lengths[:, None])[labels]
    area = 0.5 * np.bincount(labels, cross2(centred, centred[nxt]), minlength=ncurves)
    tangent = pts[nxt] - pts[prev]
    left = cross2(normals, tangent) / np.maximum(norm2(tangent), np.finfo(np.float64).tiny)
    vote = np.bincount(labels, left, minlength=ncurves) / lengths
    bad = np.flatnonzero((np.abs(vote) < 0.5) | (area == 0))
    if bad.size:
        k = int(bad[0])
        raise ValueError(
            f"the normals of curve {k} (near {_at(pts[offsets[k]])}) do not point to one side "
            "of it: components overlapping or a curve crossing itself"
        )
    encloses = (vote > 0) == (area > 0)
    lo, hi = np.asarray(boundary.bounding_box(), dtype=np.float64)
    far = hi + max(float(norm2(hi - lo)), 1.0)
    far_inside = bool(boundary.sign(far[None, :])[0] < 0)
    return CurveSamples(
        points=readonly(pts),
        normals=readonly(normals),
        labels=readonly(labels),
        offsets=readonly(offsets),
        num_curves=ncurves,
        encloses_domain=readonly(encloses),
        expected_pieces=int(encloses.sum()) + int(far_inside),
        spacing=float(norm2(pts[nxt] - pts).max()),
    )


# ----------------------------------------------------------------------------- medial radius
@dataclass(frozen=True)
class _Triangulation:
    """Delaunay neighbours of the samples: ``nbr[indptr[i]:indptr[i + 1]]`` for sample ``i``."""

    x: Float  # samples shifted to the centre of their bounding box (n, 2)
    indptr: Int  # (n + 1,)
    nbr: Int  # (2 * edges,)
    dup: Bool  # (n,): samples that coincide with another one (left out by qhull)


def _triangulate(samples: CurveSamples) -> _Triangulation:
    """Delaunay neighbours of the samples, triangulated after a tiny deterministic jitter.

    Samples of a circle are exactly co-circular: qhull then needs its point at infinity
    (Qz: quadratic on such input, 10 s for 20000 points, and 10 times slower on curves in
    general) or its random joggle (QJ: nondeterministic, and coarse: it changes the
    neighbours of nearly co-circular samples, which moves the radii by 1e-6 relative at
    128 samples per radius, growing like 1 / spacing^2). The deterministic jitter of
    ``_JITTER`` spacings breaks exact co-circularity far above qhull's rounding; the radii
    are computed from the exact samples (see :func:`_radii`).
    """
    pts = samples.points
    x = pts - 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    nxt = np.arange(1, len(x) + 1)
    nxt[samples.offsets[1:] - 1] = samples.offsets[:-1]
    scale = float(np.median(norm2(x[nxt] - x)))
    rng = np.random.default_rng(20140301)
    xj = x + rng.uniform(-_JITTER, _JITTER, x.shape) * scale
    try:  # without Qz (the point at infinity): 10 times faster on curves
        tri = Delaunay(xj, qhull_options="Qbb Qc Q12")
    except QhullError:
        tri = Delaunay(xj, qhull_options="Qbb Qc Qz Q12")
    indptr, nbr = tri.vertex_neighbor_vertices
    dup = np.zeros(len(x), dtype=bool)
    if len(tri.coplanar):
        dup[tri.coplanar[:, 0]] = True
        dup[tri.coplanar[:, 2]] = True
    return _Triangulation(x, indptr.astype(np.intp), nbr.astype(np.intp), dup)


def _window(samples: CurveSamples) -> Int:
    """The ``_WINDOW`` samples before and after each sample along its curve ``(n, 2 W)``."""
    off, lab = samples.offsets, samples.labels
    start, size = off[:-1][lab], np.diff(off)[lab]
    k = np.concatenate([np.arange(-_WINDOW, 0), np.arange(1, _WINDOW + 1)])
    i = np.arange(len(lab))[:, None] - start[:, None]
    return start[:, None] + (i + k[None, :]) % size[:, None]


def _side_minima(x: Float, n: Float, i: Int, j: Int) -> tuple[Float, Float]:
    """``|q - p|^2 / (2 |(q - p).n|)`` for pairs ``(p, q) = (x[i], x[j])``, per side (inf off)."""
    v = x[j] - x[i]
    vv = (v * v).sum(axis=-1)
    vn = (v * n[i]).sum(axis=-1)
    tol = _NOISE * np.sqrt(vv)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = vv / (2 * np.abs(vn))
    return np.where(vn < -tol, g, np.inf), np.where(vn > tol, g, np.inf)


def _radii(samples: CurveSamples, tri: _Triangulation, r_max: float | None) -> tuple[Float, Float]:
    """Tangent-disc radii from the Delaunay neighbours and the neighbours along the curve."""
    x, n = tri.x, samples.normals
    if r_max is None:
        r_max = float(norm2(x.max(axis=0) - x.min(axis=0)))
    deg = np.diff(tri.indptr)
    has, starts = deg > 0, tri.indptr[:-1][deg > 0]
    g_in, g_out = _side_minima(x, n, np.repeat(np.arange(len(x)), deg), tri.nbr)
    w = _window(samples)
    w_in, w_out = _side_minima(x, n, np.broadcast_to(np.arange(len(x))[:, None], w.shape), w)
    out = []
    for g, gw in ((g_in, w_in), (g_out, w_out)):  # inside (centre p - r n), outside (p + r n)
        r = gw.min(axis=1) if w.shape[1] else np.full(len(x), np.inf)
        if len(g):
            r[has] = np.minimum(r[has], np.minimum.reduceat(g, starts))
        r[tri.dup] = 0.0
        out.append(np.minimum(r, r_max))
    return out[0], out[1]


def medial_radius(samples: CurveSamples, r_max: float | None = None) -> tuple[Float, Float]:
    """Radii of the largest sample-free discs tangent to Gamma at each sample, on each side.

    For the sample ``p`` with outward normal ``n``, the disc of centre ``p - r n`` (inside)
    or ``p + r n`` (outside) and radius ``r`` contains no sample iff
    ``r <= |q - p|^2 / (2 |(q - p).n|)`` for every sample ``q`` on that side
    (``(q - p).n`` negative inside, positive outside), so the radius is the minimum of that
    over ``q``. Equivalently the centre leaves the Voronoi cell of ``p`` there, so only the
    Delaunay neighbours of ``p`` can attain the minimum: it is computed from one Delaunay
    triangulation (``O(n log n)``, no search tolerance, no iteration) over those neighbours
    and the 4 samples on either side along the curve. The triangulation is of the samples
    jittered by ``1e-7`` spacings (to break the exact co-circularity of circle samples, on
    which qhull is slow or imprecise); the ratios use the exact samples. Samples ``q`` with
    ``|(q - p).n| <= 1e-12 |q - p|`` (on the tangent line: straight parts, rounding) are
    ignored. Samples that coincide with another sample get 0 on both sides.

    Accuracy: the result is the exact discrete value up to rounding (relative
    ``~ eps |p| r / s^2`` through the near neighbours, ``s`` the spacing) and the jitter
    (relative ``<~ 1e-8 r / s``; both checked against the O(n^2) definition in the tests).
    It is an upper bound of the continuous value ``r_c`` (the minimum over all points of
    Gamma). Where the minimum is attained at a smooth point (the disc touches Gamma again,
    or ``r_c`` is the radius of curvature at ``p``), the sampling error is quadratic:
    ``0 <= r - r_c <~ r_c (s / r_c)^2 / 8`` (``/ 16`` for a gap between two curves;
    measured in the tests). Features below the spacing are not seen.

    Parameters
    ----------
    samples
        Dense samples of Gamma (:func:`curve_samples`).
    r_max
        Cap of the radii (default: the diagonal of the samples' bounding box).

    Returns
    -------
    r_inside, r_outside
        ``(n,)`` each. The local feature size at a sample is their minimum: at most the
        radius of curvature on the concave side, half a neck width, half the thickness of a
        thin part, half a gap between two parts of Gamma.
    """
    return _radii(samples, _triangulate(samples), r_max)


def _separation(samples: CurveSamples, tri: _Triangulation) -> tuple[float, Float]:
    """Upper estimate of the smallest feature from close pairs of samples, and where.

    Half the length of Delaunay edges between different curves (half a gap bounds the
    feature there), or between samples of one curve whose shorter arc between them is over
    twice their distance (across a neck). It sees gaps and necks narrower than the spacing,
    which the tangent discs may miss.
    """
    deg = np.diff(tri.indptr)
    i = np.repeat(np.arange(len(tri.x)), deg)
    j = tri.nbr
    keep = i < j
    i, j = i[keep], j[keep]
    lab = samples.labels
    chord = norm2(tri.x[j] - tri.x[i])
    off = samples.offsets
    step = norm2(np.roll(tri.x, -1, axis=0) - tri.x)
    last = off[1:] - 1
    step[last] = norm2(tri.x[off[:-1]] - tri.x[last])  # closing edge of each curve
    cum = np.cumsum(step) - step  # arc length from the start of the sample's curve
    cum -= np.repeat(cum[off[:-1]], np.diff(off))
    length = np.add.reduceat(step, off[:-1])
    d = np.abs(cum[i] - cum[j])
    arc = np.minimum(d, length[lab[i]] - d)
    close = (lab[i] != lab[j]) | (arc > 2 * chord)
    if not close.any():
        return np.inf, np.zeros(2)
    k = int(np.argmin(np.where(close, chord, np.inf)))
    return 0.5 * float(chord[k]), samples.points[[i[k], j[k]]].mean(axis=0)


def feature_size(
    boundary: Boundary, spacing: float | None = None, *, max_samples: int = MAX_SAMPLES
) -> tuple[CurveSamples, Float]:
    """Samples of Gamma and the local feature size at each, sampled finely enough.

    Without ``spacing``: sample at the bounding-box diagonal / 1024, compute the feature
    size (:func:`medial_radius`), and while the smallest feature (or the separation estimate
    of close pairs of samples: gaps and necks narrower than the spacing) is below
    :data:`RESOLUTION` spacings, re-sample at ``0.8 * smallest / RESOLUTION``, never finer
    than about ``max_samples`` samples in all. The relative error of the result is then
    about ``(1/16)^2 / 8 < 1e-3`` (see :func:`medial_radius`), at worst ``(1/4)^2 / 8``
    when the budget is reached.

    Parameters
    ----------
    boundary
        The boundary Gamma.
    spacing
        Fixed spacing (one sampling, no refinement).
    max_samples
        Sampling budget.

    Returns
    -------
    samples
        The samples (:func:`curve_samples`).
    feature
        ``min(r_inside, r_outside)`` at each sample ``(n,)``.

    Raises
    ------
    ValueError
        A feature smaller than :data:`MIN_RESOLUTION` spacings at the finest sampling
        allowed (or at the given ``spacing``): components touching or overlapping, a curve
        crossing itself, or a neck or gap too thin for the budget.
    """
    lo, hi = np.asarray(boundary.bounding_box(), dtype=np.float64)
    diagonal = float(norm2(hi - lo))
    finest = 1.25 * float(boundary.length()) / int(max_samples)
    s = (
        positive(spacing, "spacing")
        if spacing is not None
        else max(diagonal / _INITIAL_CELLS, finest)
    )
    while True:
        samples = curve_samples(boundary, s)
        tri = _triangulate(samples)
        r_in, r_out = _radii(samples, tri, diagonal)
        feature = np.minimum(r_in, r_out)
        k = int(np.argmin(feature))
        sep, sep_at = _separation(samples, tri)
        smallest = min(float(feature[k]), sep)
        at = samples.points[k] if feature[k] <= sep else sep_at
        h = samples.spacing
        if smallest >= RESOLUTION * h:
            return samples, feature
        if spacing is not None or s <= finest or h <= finest:
            if smallest >= MIN_RESOLUTION * h:
                return samples, feature
            gap = narrow_gap(boundary, at, max(2.5 * smallest, MIN_RESOLUTION * h))
            raise ValueError(
                (f"{gap}: " if gap else "")
                + f"the boundary has a feature of size {smallest:.3g} near {_at(at)} that "
                f"{len(samples.points)} samples {h:.3g} apart cannot resolve (at least "
                f"{MIN_RESOLUTION:g} samples across it are needed): components touching or "
                "overlapping, a curve crossing itself, or a neck or gap too thin; separate "
                + (
                    "the parts or pass a smaller spacing"
                    if spacing is not None
                    else f"the parts or raise max_samples (now {max_samples})"
                )
            )
        s = max(0.8 * smallest / RESOLUTION, finest)


# ----------------------------------------------------------------------------- target sizes
def feature_divisor(degree: int) -> float:
    """The ratio ``c(degree)`` of :data:`FEATURE_DIVISOR` (largest key for higher degrees)."""
    if int(degree) != degree or degree < 1:
        raise ValueError(f"degree must be a positive integer, got {degree!r}")
    return float(FEATURE_DIVISOR[min(int(degree), max(FEATURE_DIVISOR))])


def target_sizes(
    feature: npt.ArrayLike, h_max: float, degree: int, factor: float | None = None
) -> Float:
    """Target mesh size near Gamma: ``min(h_max, feature / c)``.

    Parameters
    ----------
    feature
        Local feature sizes ``(n,)`` (:func:`feature_size`).
    h_max
        Largest size.
    degree
        Geometry degree; sets ``c = feature_divisor(degree)`` (3 for degrees 1-2, 4 above).
    factor
        ``c`` itself, overriding the default.

    Returns
    -------
    ``(n,)`` target sizes.
    """
    c = feature_divisor(degree) if factor is None else positive(factor, "factor")
    f = np.asarray(feature, dtype=np.float64).reshape(-1)
    if not (f > 0).all():
        raise ValueError("feature sizes must be positive")
    return np.minimum(positive(h_max, "h_max"), f / c)


# ----------------------------------------------------------------------------- size fields
class _Sources:
    """Point sources of one gradation, with their evaluation structures (built on first use,
    cached per ``(h_max, ratio)``, shared by the fields made from them, not pickled)."""

    def __init__(self, points: Float, sizes: Float, gradation: float) -> None:
        self.points, self.sizes, self.gradation = points, sizes, gradation
        self.cache: dict[tuple[float, float], _Bins] = {}

    def bins(self, h_max: float, ratio: float) -> _Bins:
        key = (h_max, ratio)
        if key not in self.cache:
            self.cache[key] = _Bins(self, h_max, ratio)
        return self.cache[key]

    def __getstate__(self) -> dict[str, object]:
        return {"points": self.points, "sizes": self.sizes, "gradation": self.gradation}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["points"], state["sizes"], state["gradation"])  # type: ignore[misc]


class _Bins:
    """The sources below ``h_max`` in geometric bins of size, as lattice representatives.

    With ``R = ratio``: bin ``k`` holds the sizes in ``[a, a rb)``, ``a = rb^k``,
    ``rb = R^0.7``; its value is ``V(x) = s + g max(d(x) - e, 0)`` (``s``: its smallest size,
    ``d``: distance to its representatives, ``g``: gradation). The representatives are the
    centres of the occupied cells of a lattice of side ``c = delta a / (g sqrt 2)``
    (``delta = 1 - R^-0.3``), within ``e = c / sqrt 2`` of a source and every source within
    ``e`` of one (or the sources themselves, ``e = 0``, when that is not fewer). So
    ``V <= h_b <= V R`` for the bin's exact envelope ``h_b`` and ``V`` is ``g``-Lipschitz.
    The representatives are spaced like the sizes (``c = 0.16 a`` for the defaults): a
    circle with sizes a third of its radius has about 120, so nearest queries stay cheap
    even from its centre, equidistant to all of them.

    Queries are pruned by a grid lower bound of ``d`` per bin (Euclidean distance transform
    of the occupied cells, less a cell diagonal) over the sources' box padded by the largest
    reach ``(h_max - s_min) / g + e``; the bins that cannot lower ``h`` are skipped, so the
    result is exactly ``min(h, min_b V_b)``.
    """

    def __init__(self, src: _Sources, h_max: float, ratio: float) -> None:
        keep = src.sizes < h_max
        p, s = src.points[keep], src.sizes[keep]
        self.gradation = g = src.gradation
        self.bins: list[tuple[Float, float, float, cKDTree]] = []  # (reps (m, 2), s, e, tree)
        if not len(s):
            return
        rb, delta = ratio**0.7, 1 - ratio**-0.3
        key = np.floor(np.log(s) / np.log(rb)).astype(np.intp)
        order = np.argsort(key, kind="stable")
        key, p, s = key[order], p[order], s[order]
        cut = np.flatnonzero(np.diff(key)) + 1
        for pb, sb, kb in zip(np.split(p, cut), np.split(s, cut), key[np.r_[0, cut]]):
            c = delta * rb ** float(kb) / (g * np.sqrt(2.0))  # lattice anchored at 0
            ij = np.floor(pb / c).astype(np.int64)
            base = ij.min(axis=0)
            ij -= base
            ny = int(ij[:, 1].max()) + 1
            flat = np.unique(ij[:, 0] * ny + ij[:, 1])
            if len(flat) < len(pb):
                cells = np.column_stack([flat // ny, flat % ny]) + base
                rp, e = (cells + 0.5) * c, c / np.sqrt(2.0)
            else:
                rp, e = pb, 0.0
            self.bins.append((rp, float(sb.min()), float(e), cKDTree(rp)))
        reach = (h_max - float(s.min())) / g + max(b[2] for b in self.bins)
        allp = np.concatenate([b[0] for b in self.bins])
        self.lo = allp.min(axis=0) - reach
        span = allp.max(axis=0) + reach - self.lo
        self.cell = max(float(span.max()) / _GRID_CELLS, np.finfo(np.float64).tiny)
        self.shape = np.floor(span / self.cell).astype(np.intp) + 1
        lbs = []
        for rp, *_ in self.bins:
            ij = np.minimum(np.floor((rp - self.lo) / self.cell).astype(np.intp), self.shape - 1)
            free = np.ones(tuple(self.shape), dtype=bool)
            free[ij[:, 0], ij[:, 1]] = False
            d = ndimage.distance_transform_edt(free)
            lbs.append((np.maximum(d - np.sqrt(2.0), 0.0) * self.cell * (1 - 1e-6)).ravel())
        self.lb = np.array(lbs, dtype=np.float32)  # (bins, cells)

    def lower(self, x: Float, h: Float) -> None:
        """``h = min(h, min_b V_b(x))`` in place, for points ``x (n, 2)``, ``h (n,)``."""
        if not self.bins or not len(x):
            return
        g = self.gradation
        u = np.floor((x - self.lo) / self.cell)
        inside = (u >= 0).all(axis=1) & (u[:, 0] < self.shape[0]) & (u[:, 1] < self.shape[1])
        pts = np.flatnonzero(inside)  # outside: beyond the reach of every bin
        cells = (u[pts, 0] * self.shape[1] + u[pts, 1]).astype(np.intp)
        for (_, s_b, e, tree), lb in zip(self.bins, self.lb):
            more = h[pts] > s_b  # s_b grows and h shrinks: dropped points stay dropped
            pts, cells = pts[more], cells[more]
            if not pts.size:
                return
            cand = pts[s_b + g * np.maximum(lb[cells] - e, 0.0) < h[pts]]
            if not cand.size:
                continue
            hc = h[cand]
            bound = (float(hc.max()) - s_b) / g + e
            d = kd_query(tree, x[cand], distance_upper_bound=bound)[0]
            h[cand] = np.minimum(hc, s_b + g * np.maximum(d - e, 0.0))


def _stack(parts: npt.ArrayLike | Sequence[npt.ArrayLike], name: str, ncols: int) -> Float:
    """One array from an array or a sequence of arrays (``(m, 2)`` points, ``(m,)`` sizes)."""
    seq: list[npt.ArrayLike]
    if isinstance(parts, np.ndarray) or not isinstance(parts, Sequence):
        seq = [parts]
    else:
        try:
            a = np.asarray(parts, dtype=np.float64)
            seq = [a] if a.ndim == (2 if ncols else 1) else list(parts)
        except ValueError:  # ragged: several arrays
            seq = list(parts)
    if ncols:
        out = [_points(p, name) for p in seq]
        return np.concatenate(out) if out else np.empty((0, 2))
    arr = [np.asarray(p, dtype=np.float64).reshape(-1) for p in seq]
    return np.concatenate(arr) if arr else np.empty(0)


class SizeField:
    """The largest size function below ``h_max``, the sizes at points, and ``gradation``.

    ``h(x) = min(h_max, min_i (s_i + gradation |x - p_i|))``: the largest function with
    ``h(p_i) <= s_i``, ``h <= h_max`` and Lipschitz constant ``gradation``.

    Evaluation (see :class:`_Bins`): the sources with ``s_i < h_max`` are binned by size
    (geometric bins), each bin is represented by lattice points at a spacing proportional
    to its size, and contributes ``s_b + gradation max(dist(x, reps) - e_b, 0)`` (nearest
    representative by k-d tree, with distance bounds, and the bins that cannot lower the
    value skipped by grid lower bounds). The result ``H`` is conservative, within a factor
    ``ratio`` of the exact envelope ``h`` everywhere, ``h / ratio <= H <= h``, and exactly
    ``gradation``-Lipschitz (a minimum of such functions); ``H(p_i) <= s_i``. Cost: one
    bounded nearest query per point and size bin that may lower it (0.6 s for 1e6 points
    and the 7e4 samples of a domain with sizes from 0.0017 to ``h_max = 0.1``; 4 s when
    ``h_max = 0.5`` brings the whole box within reach of 38 bins). The worst case is a
    large circle of uniformly small sizes with a large ``h_max``: points near its centre
    are equidistant to all its representatives (15 us per point for 3800 of them).

    Fields combine: :meth:`refined` adds point sources (refinement spots), :meth:`minimum`
    takes the minimum with another field; both keep the groups of sources apart, so the
    result is never above either field. Picklable (the trees are rebuilt on first use).

    Parameters
    ----------
    points
        Source points ``(m, 2)`` (or ``(m, 3)``).
    sizes
        Sizes there ``(m,)``, positive (values above ``h_max`` have no effect).
    h_max
        Largest size.
    gradation
        Lipschitz constant ``> 0`` (size change per unit length).
    ratio
        Relative accuracy ``> 1``.
    """

    def __init__(
        self,
        points: npt.ArrayLike,
        sizes: npt.ArrayLike,
        h_max: float,
        gradation: float = 0.2,
        *,
        ratio: float = 1.1,
    ) -> None:
        self.h_max = positive(h_max, "h_max")
        self.ratio = float(ratio)
        if not (np.isfinite(self.ratio) and self.ratio > 1):
            raise ValueError(f"ratio must be a finite number > 1, got {ratio!r}")
        self._groups: tuple[_Sources, ...] = (self._sources(points, sizes, gradation),)

    @staticmethod
    def _sources(points: npt.ArrayLike, sizes: npt.ArrayLike, gradation: float) -> _Sources:
        p = _points(points, "points")
        s = np.asarray(sizes, dtype=np.float64).reshape(-1)
        if s.size == 1 and len(p) != 1:
            s = np.full(len(p), float(s[0]))
        if s.shape != (len(p),):
            raise ValueError(f"sizes must have shape ({len(p)},), got {s.shape}")
        if not (np.isfinite(s).all() and (s > 0).all()):
            raise ValueError("sizes must be positive and finite")
        return _Sources(readonly(p), readonly(s), positive(gradation, "gradation"))

    @classmethod
    def _of(cls, groups: Sequence[_Sources], h_max: float, ratio: float) -> SizeField:
        """A field from source groups (kept apart: each group's evaluation is reused)."""
        out = cls.__new__(cls)
        out.h_max, out.ratio, out._groups = float(h_max), float(ratio), tuple(groups)
        return out

    @property
    def points(self) -> Float:
        """All source points ``(m, 2)`` (every group, in order)."""
        return np.concatenate([g.points for g in self._groups])

    @property
    def sizes(self) -> Float:
        """All source sizes ``(m,)``, matching :attr:`points`."""
        return np.concatenate([g.sizes for g in self._groups])

    @property
    def gradation(self) -> float:
        """Lipschitz constant of the field (the largest of its groups)."""
        return max(g.gradation for g in self._groups)

    def __call__(self, x: npt.ArrayLike) -> Float:
        """Sizes ``(n,)`` at points ``x (n, 2)`` (see the class docstring for the accuracy)."""
        x = _points(x, "x")
        h = np.full(len(x), self.h_max)
        for g in self._groups:
            g.bins(self.h_max, self.ratio).lower(x, h)
        return h

    def refined(
        self, points: npt.ArrayLike, sizes: npt.ArrayLike, gradation: float | None = None
    ) -> SizeField:
        """This field with more sources ``points (k, 2)``, ``sizes (k,)`` (or one size).

        ``gradation`` defaults to :attr:`gradation`. The result is the minimum of this
        field and the field of the new sources, with the same ``h_max``.
        """
        grad = self.gradation if gradation is None else gradation
        return self._of([*self._groups, self._sources(points, sizes, grad)], self.h_max, self.ratio)

    def minimum(self, other: SizeField) -> SizeField:
        """The pointwise minimum of two fields (``h_max`` the smaller, ``ratio`` too)."""
        return self._of(
            [*self._groups, *other._groups],
            min(self.h_max, other.h_max),
            min(self.ratio, other.ratio),
        )

    def __repr__(self) -> str:
        return (
            f"SizeField({len(self.points)} sources, h_max={self.h_max:g}, "
            f"gradation={self.gradation:g}, ratio={self.ratio:g})"
        )


def size_field(
    points_list: npt.ArrayLike | Sequence[npt.ArrayLike],
    sizes_list: npt.ArrayLike | Sequence[npt.ArrayLike],
    h_max: float,
    gradation: float = 0.2,
    *,
    ratio: float = 1.1,
) -> SizeField:
    """The :class:`SizeField` of the sources ``points_list`` with sizes ``sizes_list``.

    Parameters
    ----------
    points_list
        Source points: an array ``(m, 2)`` or a sequence of such arrays.
    sizes_list
        Sizes: an array ``(m,)`` or a sequence of arrays matching ``points_list``.
    h_max
        Largest size.
    gradation
        Lipschitz constant of the field.
    ratio
        Relative accuracy (see :class:`SizeField`).

    Returns
    -------
    ``h(x) = min(h_max, min_i (s_i + gradation |x - p_i|))``, evaluated within a factor
    ``ratio`` below.
    """
    p = _stack(points_list, "points", 2)
    s = _stack(sizes_list, "sizes", 0)
    return SizeField(p, s, h_max, gradation, ratio=ratio)


# ----------------------------------------------------------------------------- user fields
SizeFunction = Callable[[Float], Float]
"""A user size field: points ``(n, gdim)`` to target edge lengths ``(n,)`` (vectorised,
pointwise, and the same function on every rank); ``inf`` asks for nothing there."""


def _user_points(x: npt.ArrayLike) -> Float:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] not in (2, 3):
        raise ValueError(f"points must have shape (n, 2) or (n, 3), got {a.shape}")
    return a


class _Ramp:
    """``size_min`` up to ``dist_min``, linear to ``size_max`` at ``dist_max``, then flat."""

    def __init__(self, size_min: float, size_max: float, dist_min: float, dist_max: float):
        self.size_min = positive(size_min, "size_min")
        self.size_max = positive(size_max, "size_max")
        self.dist_min, self.dist_max = float(dist_min), float(dist_max)
        if not (np.isfinite(self.dist_min) and self.dist_min >= 0):
            raise ValueError(f"dist_min must be a finite number >= 0, got {dist_min}")
        if not (np.isfinite(self.dist_max) and self.dist_max >= self.dist_min):
            raise ValueError(f"dist_max must be finite and >= dist_min, got {dist_max}")

    def __call__(self, d: Float) -> Float:
        if self.dist_max == self.dist_min:
            return np.where(d <= self.dist_min, self.size_min, self.size_max)
        t = np.clip((d - self.dist_min) / (self.dist_max - self.dist_min), 0.0, 1.0)
        return self.size_min + t * (self.size_max - self.size_min)


class _Threshold:
    """:func:`threshold`: a ramp of the distance to a boundary or to points (picklable)."""

    def __init__(self, source: Boundary | Float, ramp: _Ramp) -> None:
        self.ramp = ramp
        self.boundary: Boundary | None = None
        self.points: Float | None = None
        if isinstance(source, Boundary):
            self.boundary = source
        else:
            self.points = readonly(_user_points(source))
            if len(self.points) == 0:
                raise ValueError("threshold needs at least one source point")
        self._tree: cKDTree | None = None

    def distance(self, x: Float) -> Float:
        if self.boundary is not None:
            gdim = getattr(self.boundary, "gdim", 2)
            x = x[:, :gdim]
            if len(x) == 0:
                return np.zeros(0)
            y = self.boundary.closest_point(x)
            return np.sqrt(np.sum((x - y) ** 2, axis=1))
        assert self.points is not None
        if self._tree is None:
            self._tree = cKDTree(self.points)
        return kd_query(self._tree, x[:, : self.points.shape[1]])[0]

    def __call__(self, x: npt.ArrayLike) -> Float:
        return self.ramp(self.distance(_user_points(x)))

    def __getstate__(self) -> dict[str, object]:
        return {**self.__dict__, "_tree": None}


def threshold(
    source: Boundary | npt.ArrayLike,
    size_min: float,
    size_max: float,
    dist_min: float,
    dist_max: float,
) -> SizeFunction:
    """A size growing with the distance to a curve, a surface or points.

    gmsh's ``Distance`` and ``Threshold`` fields in one: with ``d`` the distance of ``x`` to
    ``source``, the size is ``size_min`` where ``d <= dist_min``, grows linearly to
    ``size_max`` at ``d = dist_max`` and stays there. Give it to
    :func:`~dolfinx_universal.mesh_domain` as ``size_field`` (alone, or in the minimum of
    several fields).

    Parameters
    ----------
    source
        A :class:`~dolfinx_universal.Boundary` (curve, surface or :class:`Domain`: the
        distance to it by its closest-point map) or points ``(m, gdim)``.
    size_min, size_max
        Sizes near and far from ``source`` (positive).
    dist_min, dist_max
        Where the size starts and stops growing, ``0 <= dist_min <= dist_max``.

    Returns
    -------
    The size field, a callable ``(n, gdim) -> (n,)``.
    """
    ramp = _Ramp(size_min, size_max, dist_min, dist_max)
    src = source if isinstance(source, Boundary) else np.asarray(source, dtype=np.float64)
    return _Threshold(src, ramp)


class _BoxSize:
    """:func:`box_size`."""

    def __init__(self, box: Float, ramp: _Ramp) -> None:
        self.box, self.ramp = box, ramp

    def __call__(self, x: npt.ArrayLike) -> Float:
        p = _user_points(x)[:, : self.box.shape[1]]
        gap = np.maximum(np.maximum(self.box[0] - p, p - self.box[1]), 0.0)
        return self.ramp(np.sqrt(np.sum(gap * gap, axis=1)))


def box_size(
    box: npt.ArrayLike, size_in: float, size_out: float, thickness: float = 0.0
) -> SizeFunction:
    """The size ``size_in`` in a box and ``size_out`` outside it (gmsh's ``Box`` field).

    Parameters
    ----------
    box
        ``[[x0, y0], [x1, y1]]`` (or its 3D counterpart).
    size_in, size_out
        Sizes inside and far outside the box (positive).
    thickness
        Width of the layer around the box over which the size grows linearly from
        ``size_in`` to ``size_out`` (0: a jump at the box's boundary).

    Returns
    -------
    The size field, a callable ``(n, gdim) -> (n,)``.
    """
    return _BoxSize(readonly(as_box(box)), _Ramp(size_in, size_out, 0.0, thickness))


class MinSize:
    """The pointwise minimum of size fields."""

    def __init__(self, *fields: SizeFunction) -> None:
        self.fields = fields

    def __call__(self, x: npt.ArrayLike) -> Float:
        p = _user_points(x)
        out = np.full(len(p), np.inf)
        for f in self.fields:
            out = np.minimum(out, np.asarray(f(p), dtype=np.float64).reshape(len(p)))
        return out


def refine_size(
    mesh: Any,
    cells: npt.ArrayLike,
    size_field: SizeFunction | None = None,
    factor: float = 0.6,
    gradation: float = 0.2,
    mirror: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
) -> SizeFunction:
    """The size field of the next mesh of an adaptive loop: finer at the marked cells.

    Point sources at the vertex means of the marked ``cells`` with sizes ``factor`` times
    the local mesh size there (the longest edge of the cells around their vertices: on a
    quadtree leaf, the leaf's longest edge) or times ``size_field`` there where that is
    smaller (so that the new field is finer than the old at every marked cell), growing
    by ``gradation`` per
    unit length away from them (a :class:`SizeField`), in the minimum with ``size_field``
    (the previous loop's field, if any). Give the result to
    :func:`~dolfinx_universal.mesh_domain` as ``size_field``: the new background is finer
    at the marked cells (twice as fine for the default ``factor``), and the domain is
    conformed to it (no remeshing). Collective: the marked cells of every rank are
    gathered, so that the field is the same on every rank (and does not depend on the
    partition). Given the field of an earlier call, the sources of all rounds are kept in
    one set (one evaluation of their envelope, not one per round). Marked cells are
    usually chosen by :func:`mark_cells`.

    Parameters
    ----------
    mesh
        The current mesh (a DOLFINx mesh, straight or curved).
    cells
        Marked cells (local indices, e.g. by an error indicator) ``(k,)``.
    size_field
        The previous size field, or ``None``.
    factor
        Largest size of the new cells relative to the local mesh size, in ``(0, 1]``. The
        quadtree's sizes are powers of two: a factor in ``(0.5, 1)`` halves the marked
        leaves once (the default 0.6 leaves room for the rounding of the measured size; a
        factor of exactly 0.5 can split twice), one in ``(0.25, 0.5)`` twice.
    gradation
        Growth of the size away from the marked cells (per unit length).
    mirror
        A plane ``(point, normal)`` (a line in 2D): each source is also placed at its
        mirror image, with the same size, so that the new sources are symmetric under the
        reflection. For a domain (nearly) symmetric under it whose quantity of interest is
        a difference of the two halves' contributions, such as the lift on a body in a
        nearly symmetric flow: marking by an error indicator breaks the symmetry (the
        solution's own asymmetry, the background's cells), and the two halves'
        discretisation errors, which largely cancel in the difference on a symmetric
        refinement, then add up instead.

    Returns
    -------
    The size field, a callable ``(n, gdim) -> (n,)``.
    """
    factor = float(factor)
    if not (0 < factor <= 1):
        raise ValueError(f"factor must be in (0, 1], got {factor}")
    top = mesh.topology
    tdim, gdim = top.dim, mesh.geometry.dim
    cmap = top.index_map(tdim)
    num_cells = cmap.size_local + cmap.num_ghosts
    marked = np.unique(np.asarray(cells, dtype=np.int64).reshape(-1))
    bad = len(marked) and (marked[0] < 0 or marked[-1] >= num_cells)
    # On every rank (the rest of the function is collective): a rank's own bad indices
    # would otherwise leave the others waiting.
    raise_collective(
        mesh.comm, [f"cells must be local cell indices in [0, {num_cells})"] if bad else [],
        ValueError,
    )  # fmt: skip
    # Each cell's vertices: the geometry's first tdim + 1 nodes, in the topology's order.
    nodes = mesh.geometry.dofmaps[0][:num_cells, : tdim + 1]
    diam = cell_kernels(tdim).cell_diameters(mesh.geometry.x, nodes)
    # The local mesh size at a marked cell: the longest edge of the cells around its
    # vertices (on a quadtree leaf, the leaf's longest edge, which its refinement halves;
    # a cell's own diameter is down to 0.75 of it, and half of that would split twice).
    top.create_connectivity(tdim, 0)
    c2v = top.connectivity(tdim, 0).array.reshape(-1, tdim + 1)[:num_cells]
    vsize = largest_of_cells(top.index_map(0), c2v, diam)
    marked = marked[marked < cmap.size_local]  # each marked cell once, by its owner
    local_size = vsize[c2v[marked]].max(axis=1) if len(marked) else np.zeros(0)
    centres = mesh.geometry.x[nodes[marked], :gdim].mean(axis=1)

    def source_sizes() -> Float:
        if size_field is None or not len(marked):
            return local_size
        # Where the mesh is coarser than the field asks (the longest edge around a cell
        # near a curved boundary can exceed its leaf), the field's own size is the base:
        # otherwise the new source may ask for no less than the field and leave the
        # mesh as it is (an adaptive loop marking the same cells forever).
        wanted = np.asarray(size_field(centres), dtype=np.float64).reshape(len(marked))
        return np.minimum(local_size, wanted)

    comm = mesh.comm
    # On every rank: a user's field failing on one rank's points raises on all of them.
    source = collective_call(comm, "refine_size: the size field", source_sizes, error=ValueError)
    points = np.concatenate(comm.allgather(centres)).reshape(-1, gdim)
    sizes = np.concatenate(comm.allgather(factor * source))
    if mirror is not None:
        points, sizes = _mirrored(points, sizes, mirror, gdim)
    h_max = comm.allreduce(float(diam[: cmap.size_local].max(initial=0.0)), op=MPI.MAX)
    if len(points) == 0:  # nothing marked: the previous field
        if size_field is None:
            raise ValueError("refine_size: no cell is marked and no size field is given")
        return size_field
    h_max = 2.0 * max(h_max, float(sizes.max()))
    if isinstance(size_field, _Refined) and size_field.gradation == gradation:
        # The sources of the earlier rounds and these in one set: one evaluation of their
        # envelope instead of one per round (the same function: a minimum of envelopes of
        # one gradation is the envelope of the union).
        return _Refined(
            size_field.base,
            np.concatenate([size_field.points, points]),
            np.concatenate([size_field.sizes, sizes]),
            max(h_max, size_field.h_max),
            gradation,
        )
    return _Refined(size_field, points, sizes, h_max, gradation)


def _mirrored(
    points: Float, sizes: Float, mirror: tuple[npt.ArrayLike, npt.ArrayLike], gdim: int
) -> tuple[Float, Float]:
    """The sources ``points`` with their sizes and their mirror images in the plane
    ``mirror = (point, normal)`` with the same sizes."""
    try:
        origin, normal = (np.asarray(v, dtype=np.float64).reshape(-1) for v in mirror)
    except (TypeError, ValueError) as e:
        raise ValueError(f"mirror must be (point, normal), got {mirror!r}") from e
    length = float(np.linalg.norm(normal)) if normal.shape == (gdim,) else 0.0
    if origin.shape != (gdim,) or not np.all(np.isfinite(origin)) or not length > 0:
        raise ValueError(
            f"mirror must be (point, normal) with {gdim} finite coordinates each and a "
            f"nonzero normal, got {mirror!r}"
        )
    n = normal / length
    images = points - 2.0 * ((points - origin) @ n)[:, None] * n
    return np.concatenate([points, images]), np.concatenate([sizes, sizes])


class _Refined:
    """:func:`refine_size`'s field: ``min(base(x), min_i(s_i + g |x - p_i|))``, the point
    sources' envelope counting as no constraint (``inf``) where it reaches ``h_max``."""

    def __init__(
        self,
        base: SizeFunction | None,
        points: Float,
        sizes: Float,
        h_max: float,
        gradation: float,
    ) -> None:
        self.base, self.points, self.sizes = base, points, sizes
        self.h_max, self.gradation = h_max, positive(gradation, "gradation")
        kind = _POINT_SOURCES[points.shape[1]]
        self.sources: SizeFunction = kind(points, sizes, h_max, self.gradation)

    def __call__(self, x: npt.ArrayLike) -> Float:
        p = _user_points(x)
        h = np.asarray(self.sources(p), dtype=np.float64)
        h = np.where(h >= self.h_max, np.inf, h)
        if self.base is None:
            return h
        return np.minimum(np.asarray(self.base(p), dtype=np.float64).reshape(len(p)), h)


def mark_cells(mesh: Any, indicators: npt.ArrayLike, fraction: float = 0.5) -> Int:
    """Dörfler marking: the fewest cells that hold ``fraction`` of the squared error.

    The owned cells whose indicators are at least ``tau``, the largest value for which those
    cells' squared indicators sum to at least ``fraction`` of the global sum (Dörfler 1996,
    "A convergent adaptive algorithm for Poisson's equation", SIAM J. Numer. Anal. 33; the
    bulk criterion of the usual adaptive loop: estimate, mark, refine, solve). Every cell
    with the threshold's value is marked, so the set does not depend on the order of the
    cells or on the partition (up to the rounding of the indicators themselves).
    Collective: the indicators are gathered on rank 0 to find ``tau``.

    Parameters
    ----------
    mesh
        The mesh (its communicator and owned cells).
    indicators
        Error indicators ``eta_K >= 0`` of the owned cells ``(num_owned,)`` (or of the owned
        and ghost cells: the ghosts are ignored).
    fraction
        Dörfler's ``theta`` in ``(0, 1]``.

    Returns
    -------
    The marked owned cells (local indices) ``(k,)``: give them to :func:`refine_size`.
    """
    fraction = float(fraction)
    if not (0 < fraction <= 1):
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    tdim = mesh.topology.dim
    n = mesh.topology.index_map(tdim).size_local
    eta = np.asarray(indicators, dtype=np.float64).reshape(-1)
    comm = mesh.comm
    problems = []
    if len(eta) < n:
        problems.append(
            f"indicators must have one value per owned cell on every rank (a rank has {n} "
            f"cells and {len(eta)} values)"
        )
    eta = eta[:n]
    if np.any(~(eta >= 0)) or np.any(~np.isfinite(eta)):
        problems.append("indicators must be finite and >= 0")
    # On every rank: a rank raising alone would leave the others in the gather.
    raise_collective(comm, problems, ValueError)
    gathered = comm.gather(eta, root=0)
    tau = None
    if comm.rank == 0:
        assert gathered is not None
        values = np.sort(np.concatenate(gathered))[::-1]
        if len(values) == 0 or values[0] == 0.0:
            tau = np.inf  # no error anywhere: nothing to mark
        else:
            total = np.cumsum(values * values)
            k = int(np.searchsorted(total, fraction * total[-1] * (1 - 1e-12)))
            tau = float(values[min(k, len(values) - 1)])
    tau = comm.bcast(tau, root=0)
    return np.flatnonzero(eta >= tau).astype(np.int32)


class _GradedSources:
    """``min(h_max, min_i (s_i + g |x - p_i|))`` in any dimension, from below within 10 %:
    the sources in geometric bins of size (ratio 1.1), each bin contributing its smallest
    size plus ``g`` times the distance to its nearest source (k-d trees; no grid)."""

    def __init__(self, points: Float, sizes: Float, h_max: float, gradation: float) -> None:
        self.h_max, self.gradation = h_max, gradation
        key = np.floor(np.log(sizes) / np.log(1.1)).astype(np.intp)
        self.bins = [(float(sizes[key == k].min()), points[key == k]) for k in np.unique(key)]
        self._trees: list[cKDTree] | None = None

    def __call__(self, x: npt.ArrayLike) -> Float:
        p = _user_points(x)
        if self._trees is None:
            self._trees = [cKDTree(pts) for _, pts in self.bins]
        h = np.full(len(p), self.h_max)
        for (s_b, pts), tree in zip(self.bins, self._trees):
            more = np.flatnonzero(h > s_b)
            if not len(more):
                continue
            bound = (float(h[more].max()) - s_b) / self.gradation
            d = kd_query(tree, p[more, : pts.shape[1]], distance_upper_bound=bound)[0]
            h[more] = np.minimum(h[more], s_b + self.gradation * d)
        return h

    def __getstate__(self) -> dict[str, object]:
        return {**self.__dict__, "_trees": None}


_POINT_SOURCES: dict[int, Callable[[Float, Float, float, float], SizeFunction]] = {
    2: SizeField,
    3: _GradedSources,
}
"""The envelope of point sources of :func:`refine_size` by dimension: the grid field of
:class:`SizeField` in the plane, binned k-d trees in space."""
