"""Quality figures of tetrahedra: dihedral angles, radius and mean ratios, volume ratios."""

from __future__ import annotations

from typing import Any

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from dolfinx_universal.cells import tet

__all__ = ["shape_figures"]


def shape_figures(
    comm: MPI.Comm,
    x: npt.NDArray[np.float64],
    background_x: npt.NDArray[np.float64],
    cells: npt.NDArray,
    sign: npt.NDArray[np.float64],
) -> dict[str, Any]:
    """Dihedral angle, radius ratio, mean ratio and volume figures of tetrahedra, reduced over
    ``comm`` (collective; the arguments of
    :func:`~dolfinx_universal.conforming.quality.cell_quality`).

    Orientation and volume ratio are taken against the background tetrahedra (DOLFINx
    does not orient tetrahedra, so either sign is valid there)."""
    vol0 = tet.signed_volumes(background_x, cells)
    s, vol1 = tet.summary_and_volumes(x, cells, np.where(vol0 < 0, -1.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = vol1 / vol0
    hist = np.ascontiguousarray(s["dihedral_histogram"], dtype=np.int64)
    total = np.zeros_like(hist)
    comm.Allreduce(hist, total, op=MPI.SUM)
    return {
        "theta_min_deg": comm.allreduce(float(s["dihedral_min_deg"]), op=MPI.MIN),
        "theta_max_deg": comm.allreduce(float(s["dihedral_max_deg"]), op=MPI.MAX),
        "dihedral_histogram": [int(c) for c in total],
        "radius_ratio_min": comm.allreduce(float(s["radius_ratio_min"]), op=MPI.MIN),
        "mean_ratio_min": comm.allreduce(float(s["mean_ratio_min"]), op=MPI.MIN),
        "n_inverted": comm.allreduce(int(s["n_inverted"]), op=MPI.SUM),
        "min_volume_ratio": comm.allreduce(
            float(ratio.min()) if len(cells) else np.inf, op=MPI.MIN
        ),
    }
