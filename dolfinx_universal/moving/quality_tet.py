"""Quality of a moving domain's tetrahedra that the step left as in the background."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from dolfinx_universal.cells import tet
from dolfinx_universal.core.arrays import Float, Int

__all__ = ["HISTOGRAM_BINS", "background_quality", "merge_far"]

HISTOGRAM_BINS = len(tet.DIHEDRAL_BIN_EDGES) - 1
"""Bins of the dihedral-angle histogram
(:data:`~dolfinx_universal.cells.tet.DIHEDRAL_BIN_EDGES`)."""


def background_quality(x: Float, cells: Int) -> dict[str, npt.NDArray[Any]]:
    """Per-cell quality of background tetrahedra ``cells (m, 4)``: the smallest and largest
    dihedral angles (degrees), the radius ratio ``rr`` and the mean ratio ``mr``, and each
    dihedral angle's histogram bin (``bins``, ``(m, 6)``)."""
    ang = np.degrees(tet.dihedral_angles(x, cells))
    bins = np.searchsorted(tet.DIHEDRAL_BIN_EDGES, ang, side="right") - 1
    bins = np.clip(bins, 0, len(tet.DIHEDRAL_BIN_EDGES) - 2).astype(np.int8)
    return {
        "theta_min": ang.min(axis=1),
        "theta_max": ang.max(axis=1),
        "rr": tet.radius_ratio(x, cells),
        "mr": np.abs(tet.mean_ratio(x, cells)),
        "bins": bins,
    }


def merge_far(
    report: dict[str, Any],
    extreme: Callable[[str, Callable[..., Any], float], float],
    histogram: Callable[[], npt.NDArray[np.int64]],
) -> None:
    """Fold the unaltered tetrahedra's background quality into ``report`` (from
    :func:`~dolfinx_universal.conforming.quality.cell_quality`): ``extreme(key, op, empty)``
    is the collective extreme of a :func:`background_quality` entry over them,
    ``histogram()`` the global dihedral histogram of their angles (collective)."""
    report["radius_ratio_min"] = min(report["radius_ratio_min"], extreme("rr", np.min, 1.0))
    report["mean_ratio_min"] = min(report["mean_ratio_min"], extreme("mr", np.min, 1.0))
    report["min_volume_ratio"] = min(report["min_volume_ratio"], 1.0)
    report["dihedral_histogram"] = [
        int(a + c) for a, c in zip(report["dihedral_histogram"], histogram())
    ]
