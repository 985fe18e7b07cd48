"""Which components of a domain touch or nearly touch: the diagnosis of a gap too narrow."""

from __future__ import annotations

import numpy as np

from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.boundaries.domains import Domain
from dolfinx_universal.core.arrays import Float
from dolfinx_universal.core.collective import where

__all__ = ["narrow_gap"]


def narrow_gap(boundary: Boundary, point: Float, within: float) -> str:
    """Which components of a :class:`~dolfinx_universal.boundaries.domains.Domain` touch or
    nearly touch at ``point`` (``(1, gdim)``, on Gamma): the component through the point and
    the nearest other one, where that is within ``within`` of the point; ``""`` where none
    is (a thin part or high curvature of one component) or a closest point cannot be found.

    Components are named as :attr:`~dolfinx_universal.boundaries.domains.Domain.components`
    orders them: ``"the container"``, ``"body k"`` (``k`` the index there).
    """
    if not isinstance(boundary, Domain) or len(boundary.components) < 2:
        return ""
    p = np.asarray(point, dtype=np.float64).reshape(1, -1)
    names = [
        f"body {k}" if body else "the container" for k, (_, body) in enumerate(boundary.components)
    ]
    try:
        near = [np.asarray(b.closest_point(p), dtype=np.float64) for b, _ in boundary.components]
    except (RuntimeError, ValueError, FloatingPointError):  # no projection found: no note
        return ""
    dist = np.array([float(np.linalg.norm(p - q.reshape(p.shape))) for q in near])
    own = int(np.argmin(dist))
    dist[own] = np.inf
    other = int(np.argmin(dist))
    if not dist[other] <= within:
        return ""
    first, second = sorted((own, other))
    return (
        f"{names[first]} and {names[second]} touch or nearly touch near {where(p)} (they "
        f"come within {dist[other]:.3g} of each other there)"
    )
