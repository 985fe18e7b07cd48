"""Quality of a moving domain's triangles that the step left as in the background."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from dolfinx_universal.conforming.classify import interior_angles
from dolfinx_universal.conforming.quality import edge_ratio, radius_ratio
from dolfinx_universal.core.arrays import Float, Int

__all__ = ["HISTOGRAM_BINS", "background_quality", "merge_far"]

HISTOGRAM_BINS = 0
"""Triangles report no angle histogram."""


def background_quality(x: Float, cells: Int) -> dict[str, npt.NDArray[Any]]:
    """Per-cell quality of background triangles ``cells (m, 3)``: the smallest and largest
    interior angles (degrees), the radius ratio ``q`` and the edge ratio ``Q``, and no
    histogram bins (``bins``, ``(m, 0)``)."""
    ang = np.degrees(interior_angles(x, cells))
    return {
        "theta_min": ang.min(axis=1),
        "theta_max": ang.max(axis=1),
        "q": radius_ratio(x, cells),
        "Q": edge_ratio(x, cells),
        "bins": np.zeros((len(cells), HISTOGRAM_BINS), dtype=np.int8),
    }


def merge_far(
    report: dict[str, Any],
    extreme: Callable[[str, Callable[..., Any], float], float],
    histogram: Callable[[], npt.NDArray[np.int64]],
) -> None:
    """Fold the unaltered triangles' background quality into ``report`` (from
    :func:`~dolfinx_universal.conforming.quality.cell_quality`): ``extreme(key, op, empty)``
    is the collective extreme of a :func:`background_quality` entry over them; ``histogram``
    is not needed for triangles."""
    report["q_max"] = max(report["q_max"], extreme("q", np.max, 0.0))
    report["Q3_max"] = max(report["Q3_max"], extreme("Q", np.max, 0.0))
    report["min_area_ratio"] = min(report["min_area_ratio"], 1.0)
