"""Quality figures of triangles: interior angles, radius and edge ratios, area ratios."""

from __future__ import annotations

from typing import Any

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from dolfinx_universal.cells.tri import edge_lengths, signed_areas, triangle_measures

__all__ = ["edge_ratio", "radius_ratio", "shape_figures"]


def edge_ratio(x: npt.NDArray[np.float64], cells: npt.NDArray) -> npt.NDArray[np.float64]:
    """``Q`` = longest edge / shortest edge of each triangle, ``(m,)`` (1 when equilateral)."""
    return _edge_ratio(edge_lengths(x, cells))


def radius_ratio(x: npt.NDArray[np.float64], cells: npt.NDArray) -> npt.NDArray[np.float64]:
    """Circumradius / inradius of each triangle, ``(m,)`` (2 when equilateral)."""
    return _radius_ratio(edge_lengths(x, cells), signed_areas(x, cells))


def _edge_ratio(e: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """:func:`edge_ratio` from the edge lengths ``(m, 3)``."""
    return e.max(axis=1) / e.min(axis=1)


def _radius_ratio(
    e: npt.NDArray[np.float64], signed_area: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """:func:`radius_ratio` from the edge lengths ``(m, 3)`` and signed areas ``(m,)``."""
    area = np.abs(signed_area)
    semi = 0.5 * e.sum(axis=1)
    circum = e.prod(axis=1) / (4.0 * area)
    inr = area / semi
    return circum / inr


def shape_figures(
    comm: MPI.Comm,
    x: npt.NDArray[np.float64],
    background_x: npt.NDArray[np.float64],
    cells: npt.NDArray,
    sign: npt.NDArray[np.float64],
) -> dict[str, Any]:
    """Angle, radius ratio, edge ratio and area figures of triangles, reduced over ``comm``
    (collective; the arguments of :func:`~dolfinx_universal.conforming.quality.cell_quality`)."""
    rad, e, area1 = triangle_measures(x, cells)  # one gather; e for both ratios
    ang = np.degrees(rad)
    neg = sign[cells] < 0
    inside = neg[:, 0].astype(np.int8) + neg[:, 1] + neg[:, 2]  # vertices inside, by columns
    Q = _edge_ratio(e)
    area0 = signed_areas(background_x, cells)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = area1 / area0

    def red(value: Any, op: MPI.Op, empty: Any) -> Any:
        return comm.allreduce(value if len(cells) else empty, op=op)

    report: dict[str, Any] = {
        "theta_min_deg": red(float(ang.min()) if len(cells) else 180.0, MPI.MIN, 180.0),
        "theta_max_deg": red(float(ang.max()) if len(cells) else 0.0, MPI.MAX, 0.0),
        "q_max": red(float(_radius_ratio(e, area1).max()) if len(cells) else 0.0, MPI.MAX, 0.0),
    }
    for k in (3, 2, 1):
        sel = Q[inside == k]
        report[f"Q{k}_max"] = comm.allreduce(float(sel.max()) if len(sel) else 0.0, MPI.MAX)
    report["n_inverted"] = red(int((ratio <= 0).sum()), MPI.SUM, 0)
    report["min_area_ratio"] = red(float(ratio.min()) if len(cells) else np.inf, MPI.MIN, np.inf)
    return report
