"""Local feature size of closed surfaces, for sizing 3D backgrounds.

The 3D counterpart of :func:`dolfinx_universal.sizing.fields.feature_size`: the local feature size
at a point of Gamma is its distance to the medial axis, on both sides of Gamma (inside and
outside the domain). It is at most the smaller principal radius of curvature on the concave
side, half the thickness of a thin part, half a gap between two parts of Gamma or between
two components.

The medial balls are found by the *shrinking-ball* algorithm (Ma, Bai, Tang & Zhang, "3D
medial axis point approximation using nearest neighbors and the normal field", The Visual
Computer 28, 2012) at dense samples with exact normals: for the sample ``p`` with outward
unit normal ``n``, the largest ball tangent to Gamma at ``p`` on one side (centre
``p - r n`` inside, ``p + r n`` outside) that Gamma does not enter. Starting from
``r = r_max``, the point ``q`` nearest to the centre is found; if it lies in the ball, the
ball is shrunk to the one through ``p`` and ``q``: ``r = |p - q|^2 / (2 |(p - q).n|)``, and
again, until the ball is empty. The radius decreases strictly, so this stops; every step is
one vectorised query of the balls not yet settled.

Ma et al. take ``q`` among the samples (a k-d tree: :func:`sample_nearest`). On surface
samples that query is slow where the ball's centre is about as far from many samples as
from the nearest (deep inside fat parts; every sample of a sphere is at the same distance
from its centre: one query then visits every sample, 50 s for the 31 000 samples of the unit
sphere at spacing 0.02), and the radii are only upper estimates (within ``r (s / r)^2``).
Every :class:`~dolfinx_universal.boundaries.base.Boundary` has an exact global closest point, so
by default the balls shrink against Gamma itself (:func:`surface_nearest`): exact radii,
3-5 closest-point evaluations per ball on average (0.4 s for the 37 000 samples of a sphere
with two spherical bodies).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.boundaries.domains import Domain
from dolfinx_universal.boundaries.motions import RigidMotion
from dolfinx_universal.boundaries.surfaces import ImplicitSurface
from dolfinx_universal.core.arrays import Float, Int, kd_query, positive, readonly

__all__ = [
    "SurfaceFeature",
    "component_boundaries",
    "sample_nearest",
    "shrinking_ball_radii",
    "surface_feature_size",
    "surface_area",
    "surface_nearest",
    "surface_samples",
]


MAX_ITERATIONS = 60
"""Most shrinking steps of a ball (they stop after 3-20 steps on smooth samples)."""

_EXCLUDE = 3.0  # first step: samples within this many spacings of p do not shrink the ball
_FIRST_NEIGHBOURS = 8  # neighbours of the first query, to skip those near p
_RTOL = 1e-12  # a ball is empty when q is within _RTOL (r + r_max) of its sphere
_ROUNDING = 16 * float(np.finfo(np.float64).eps)  # ... or within this fraction of the
# coordinates' magnitude (far from the origin their rounding exceeds _RTOL r_max)
_CHUNK = 2048  # centres per closest-point call


@dataclass(frozen=True, eq=False)
class SurfaceFeature:
    """Samples of Gamma with their normals, components and local feature size (read-only)."""

    points: Float
    """Points of Gamma ``(n, 3)``."""
    normals: Float
    """Unit normals ``(n, 3)``, pointing out of the domain (into the bodies of a
    :class:`~dolfinx_universal.boundaries.domains.Domain`)."""
    labels: Int
    """Component of each sample ``(n,)``: the index into ``Domain.components`` (container
    first), 0 for a boundary that is not a Domain."""
    feature: Float
    """Local feature size ``min(r_inside, r_outside)`` at each sample ``(n,)``."""
    r_inside: Float
    """Radius of the largest ball tangent at each sample inside the domain (centre
    ``p - r n``) that Gamma (or, with ``nearest="samples"``, any sample) does not enter,
    ``(n,)``, at most :attr:`r_max`."""
    r_outside: Float
    """The same outside the domain (centre ``p + r n``), ``(n,)``."""
    spacing: float
    """Median distance from a sample to its nearest neighbour."""
    r_max: float
    """Cap of the radii: the diagonal of the bounding box of Gamma."""


def component_boundaries(boundary: Boundary) -> list[Boundary]:
    """The components of a :class:`~dolfinx_universal.boundaries.domains.Domain` (container first),
    or ``[boundary]``."""
    if isinstance(boundary, Domain):
        return [b for b, _ in boundary.components]
    return [boundary]


def _searched(boundary: Boundary) -> bool:
    """Whether a component of ``boundary`` finds closest points by a search from seeds
    (:class:`~dolfinx_universal.boundaries.surfaces.ImplicitSurface`, also under a rigid motion)."""
    for comp in component_boundaries(boundary):
        while isinstance(comp, RigidMotion):
            comp = comp.base
        if isinstance(comp, Domain):
            if _searched(comp):
                return True
        elif isinstance(comp, ImplicitSurface):
            return True
    return False


def surface_area(surface: Boundary) -> float:
    """Area of a surface: its own (``area()``, else ``measure()``) where it has one, else
    that of its bounding box (an overestimate for convex surfaces: denser samples)."""
    for name in ("area", "measure"):
        try:
            area = float(getattr(surface, name)())
        except (AttributeError, NotImplementedError, TypeError):
            continue
        if np.isfinite(area) and area > 0:
            return area
    lo, hi = np.asarray(surface.bounding_box(), dtype=np.float64)
    a, b, c = hi - lo
    return float(2.0 * (a * b + b * c + c * a))


def surface_samples(boundary: Boundary, spacing: float) -> tuple[Float, Float, Int]:
    """About uniform samples of every component of Gamma at about ``spacing``.

    Component ``k`` gets ``ceil(area_k / spacing^2)`` samples (``component.sample``).

    Returns
    -------
    points
        ``(n, 3)``.
    normals
        Unit normals ``(n, 3)`` out of the domain (``boundary.normal``).
    labels
        Component index of each sample ``(n,)``.
    """
    spacing = positive(spacing, "spacing")
    if int(getattr(boundary, "gdim", 2)) != 3:
        raise ValueError("surface_samples needs a surface (gdim = 3); use sizing.feature_size")
    parts, labels = [], []
    for k, comp in enumerate(component_boundaries(boundary)):
        n = max(int(np.ceil(surface_area(comp) / spacing**2)), 4)
        pts = np.asarray(comp.sample(n), dtype=np.float64).reshape(-1, 3)
        parts.append(pts)
        labels.append(np.full(len(pts), k, dtype=np.intp))
    points = np.concatenate(parts)
    normals = np.asarray(boundary.normal(points), dtype=np.float64)
    normals = normals / np.linalg.norm(normals, axis=1)[:, None]
    return points, normals, np.concatenate(labels)


Nearest = Callable[[Float, Int, bool], Float]
"""``nearest(centres (m, 3), owners (m,), first) -> points (m, 3)``: the point of Gamma (or
sample) nearest to each ball centre, other than the ball's own sample ``points[owners]``;
``first`` at the first shrinking step."""


def surface_nearest(boundary: Boundary, fallback: Nearest | None = None) -> Nearest:
    """The nearest point of Gamma itself: ``boundary.closest_point`` (exact, global).

    The centres go to ``closest_point`` in chunks of :data:`_CHUNK`; a chunk where it
    raises (an :class:`~dolfinx_universal.boundaries.surfaces.ImplicitSurface` may find no converged
    projection near its medial axis) takes ``fallback`` (e.g. :func:`sample_nearest`), or
    the error is raised without one.
    """

    def nearest(c: Float, owner: Int, first: bool) -> Float:
        q = np.empty((len(c), 3))
        for lo in range(0, len(c), _CHUNK):
            part = slice(lo, lo + _CHUNK)
            try:
                q[part] = np.asarray(boundary.closest_point(c[part]), dtype=np.float64)
            except (RuntimeError, ValueError, FloatingPointError):
                if fallback is None:
                    raise
                q[part] = fallback(c[part], owner[part], first)
        return q

    return nearest


def sample_nearest(points: Float, exclude: float = 0.0, tree: cKDTree | None = None) -> Nearest:
    """The nearest sample (a k-d tree), as Ma et al.: other than the ball's own sample, and at
    the first step farther than ``exclude`` from it where one of the 8 nearest is (the
    first, huge ball is then shrunk by a far sample, not by the nearest ones)."""
    x = np.ascontiguousarray(points, dtype=np.float64)
    tree = cKDTree(x) if tree is None else tree
    k_first = min(_FIRST_NEIGHBOURS, len(x))

    def nearest(c: Float, owner: Int, first: bool) -> Float:
        k = k_first if first else min(2, len(x))
        idx = kd_query(tree, c, k=k)[1].reshape(len(c), k)
        other = idx != owner[:, None]
        choice = other.argmax(axis=1)
        if first and exclude > 0.0:
            far = other & (np.linalg.norm(x[idx] - x[owner][:, None], axis=2) > exclude)
            choice = np.where(far.any(axis=1), far.argmax(axis=1), choice)
        return x[idx[np.arange(len(c)), choice]]

    return nearest


def shrinking_ball_radii(
    points: Float,
    normals: Float,
    r_max: float,
    nearest: Nearest,
    *,
    max_iterations: int = MAX_ITERATIONS,
) -> tuple[Float, Float]:
    """Radii of the largest balls tangent to Gamma at each sample that contain no point of
    Gamma (or no sample, with :func:`sample_nearest`), on each side.

    For the ball of centre ``c = p -/+ r n``: if the nearest point ``q`` to ``c`` is in
    the ball, shrink it to the ball through ``p`` and ``q``, ``r = |p - q|^2 / (2 |(p - q).n|)``
    (``q`` in the ball is on its side of the tangent plane), and repeat; the radius only
    decreases and stays at least the true one (``q`` is outside the true ball, which is
    nested in every larger one tangent at ``p``). All balls step together; only those
    that shrank are queried again. A ball counts as empty when ``q`` is within
    ``1e-12 r + 1e-12 r_max`` of its sphere, or within the rounding of the coordinates
    (``16 eps`` times their magnitude, a few units in the last place: more than
    ``1e-12 r_max`` for a unit sphere centred beyond about 1e3; without it, a ball tangent
    at ``p`` far from the origin could find ``p`` itself inside and shrink to nothing).

    Parameters
    ----------
    points
        Samples ``(n, 3)`` of Gamma.
    normals
        Unit normals ``(n, 3)`` (out of the domain).
    r_max
        Starting (and largest) radius.
    nearest
        :func:`surface_nearest` or :func:`sample_nearest`.
    max_iterations
        Most shrinking steps (the radius stays an upper bound if they are not enough).

    Returns
    -------
    r_inside, r_outside
        ``(n,)`` each: the balls of centres ``p - r n`` and ``p + r n``.
    """
    x = np.ascontiguousarray(points, dtype=np.float64)
    nrm = np.ascontiguousarray(normals, dtype=np.float64)
    n = len(x)
    owner = np.concatenate([np.arange(n), np.arange(n)])  # inside balls, then outside ones
    side = np.concatenate([np.full(n, -1.0), np.full(n, 1.0)])
    r = np.full(2 * n, float(r_max))
    scale = float(np.abs(x).max(initial=0.0)) + float(r_max)
    slack = max(_RTOL * float(r_max), _ROUNDING * scale)
    active = np.arange(2 * n)
    for step in range(max_iterations):
        if not active.size:
            break
        i = owner[active]
        p, nv, ra = x[i], nrm[i], r[active]
        c = p + (side[active] * ra)[:, None] * nv
        q = nearest(c, i, step == 0)
        inside = np.linalg.norm(c - q, axis=1) < ra * (1.0 - _RTOL) - slack
        d = p - q
        d2 = np.einsum("ij,ij->i", d, d)
        dn = np.abs(np.einsum("ij,ij->i", d, nv))
        with np.errstate(divide="ignore", invalid="ignore"):
            r_new = np.where(d2 > 0.0, d2 / (2.0 * dn), 0.0)
        r_new = np.minimum(r_new, ra)  # inf where dn = 0 (rounding): no shrinking
        r[active[inside]] = r_new[inside]
        active = active[inside & (r_new < ra * (1.0 - _RTOL))]
    return r[:n].copy(), r[n:].copy()


def surface_feature_size(
    boundary: Boundary, spacing: float, *, nearest: str = "auto"
) -> SurfaceFeature:
    """Samples of the surface(s) Gamma and the local feature size at each.

    Samples each component at about ``spacing`` (:func:`surface_samples`), then finds the
    largest tangent ball on each side of every sample that Gamma does not enter, by the
    shrinking-ball algorithm (:func:`shrinking_ball_radii`) started at ``r_max``, the
    diagonal of the bounding box of Gamma. The feature size is the smaller radius.

    Parameters
    ----------
    boundary
        A closed surface (``gdim = 3``), or a
        :class:`~dolfinx_universal.boundaries.domains.Domain` of surfaces: the gaps between its
        components are features too.
    spacing
        Sample spacing.
    nearest
        ``"auto"`` (default): ``"samples"`` where a component is an
        :class:`~dolfinx_universal.boundaries.surfaces.ImplicitSurface` (its closest points are a
        Newton search from seeds, which may fail near the medial axis: 5 times the time of
        the k-d tree, 14 s against 2.7 s for the 7 000 samples of ``x^4 + y^4 + z^4 = 1``
        at spacing 0.05), ``"surface"`` otherwise.
        ``"surface"``: the balls shrink against Gamma itself
        (``boundary.closest_point``): the radii are those of the continuous surface, to
        rounding, at a few closest-point evaluations per sample (3-5 on average, at most
        about 25 at the tips of elongated shapes where the ball is the osculating one).
        Centres whose closest point cannot be found (``closest_point`` raises) take the
        nearest sample instead (:func:`surface_nearest`).
        ``"samples"``: against the other samples (Ma et al.'s original, with a k-d tree):
        an upper estimate, within about ``r (s / r)^2`` of the true radius where the ball
        touches Gamma at smooth points (``s`` the spacing), and features smaller than the
        spacing are not seen; each query costs about the number of samples within
        ``s`` of the ball's sphere, all of them for a sphere (quadratic cost).

    Radii limited by the sampling (features of a few spacings, seen by ``"samples"`` only
    as far as the samples resolve them) are returned as found: the sizing refines there.

    Returns
    -------
    The samples, normals (out of the domain), component labels and feature sizes.
    """
    if nearest not in ("auto", "surface", "samples"):
        raise ValueError(f"nearest must be 'auto', 'surface' or 'samples', got {nearest!r}")
    points, normals, labels = surface_samples(boundary, spacing)
    lo, hi = np.asarray(boundary.bounding_box(), dtype=np.float64)
    r_max = float(np.linalg.norm(hi - lo))
    h, tree = float(spacing), None
    if len(points) > 1:
        tree = cKDTree(points)
        h = float(np.median(kd_query(tree, points, k=2)[0][:, 1]))
    samples = sample_nearest(points, _EXCLUDE * h, tree)
    if nearest == "auto":
        nearest = "samples" if _searched(boundary) else "surface"
    oracle = surface_nearest(boundary, samples) if nearest == "surface" else samples
    r_in, r_out = shrinking_ball_radii(points, normals, r_max, oracle)
    return SurfaceFeature(
        points=readonly(points),
        normals=readonly(normals),
        labels=readonly(labels),
        feature=readonly(np.minimum(r_in, r_out)),
        r_inside=readonly(r_in),
        r_outside=readonly(r_out),
        spacing=h,
        r_max=r_max,
    )
