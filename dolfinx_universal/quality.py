"""Quality of conforming meshes: angles, radius ratios, edge ratios, what was altered."""

from __future__ import annotations

from typing import TYPE_CHECKING

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from ._geometry import edge_lengths, interior_angles, signed_areas
from .classify import positively_cut

if TYPE_CHECKING:
    from .conform import ConformingMesh

__all__ = ["background_positions", "cell_quality", "edge_ratio", "quality_report", "radius_ratio"]


def edge_ratio(x: npt.NDArray[np.float64], cells: npt.NDArray) -> npt.NDArray[np.float64]:
    """``Q`` = longest edge / shortest edge of each triangle, ``(m,)`` (1 when equilateral)."""
    e = edge_lengths(x, cells)
    return e.max(axis=1) / e.min(axis=1)


def radius_ratio(x: npt.NDArray[np.float64], cells: npt.NDArray) -> npt.NDArray[np.float64]:
    """Circumradius / inradius of each triangle, ``(m,)`` (2 when equilateral)."""
    e = edge_lengths(x, cells)
    area = np.abs(signed_areas(x, cells))
    semi = 0.5 * e.sum(axis=1)
    circum = e.prod(axis=1) / (4.0 * area)
    inr = area / semi
    return circum / inr


def quality_report(cm: ConformingMesh) -> dict[str, float | int]:
    """Global quality figures of a conforming mesh (collective).

    Returns
    -------
    A dict with ``n_cells`` (triangles kept), ``n_positively_cut``, ``n_unaltered`` (no vertex
    moved), ``percent_unaltered``, ``theta_min_deg``, ``theta_max_deg``, ``q_max`` (max
    circumradius/inradius), ``Q3_max``, ``Q2_max``, ``Q1_max`` (max longest/shortest edge
    over triangles with 3, 2 and 1 vertices inside the domain; 0 when there are none),
    ``n_inverted`` and ``min_area_ratio`` (conforming area over the area of the triangle in
    the original background: the relaxation may move ``background_x`` of the vertices on
    Gamma, the orientation is checked against the background itself).
    """
    nco = cm.mesh.topology.index_map(2).size_local
    return cell_quality(
        cm.mesh.comm, cm.x, background_positions(cm), cm.cells[:nco], cm.sign, cm.moved
    )


def background_positions(cm: ConformingMesh) -> npt.NDArray[np.float64]:
    """Original background positions of the vertices of ``cm``, ``(num_vertices, 2)``."""
    bg = cm.background
    topo = bg.topology
    topo.create_connectivity(2, 0)
    c2v = topo.connectivity(2, 0).array.reshape(-1, 3)
    imv = topo.index_map(0)
    v2n = np.empty(imv.size_local + imv.num_ghosts, dtype=np.int32)
    v2n[c2v] = bg.geometry.dofmaps[0][:, :3]
    return bg.geometry.x[v2n[cm.vertex_map], :2]


def cell_quality(
    comm: MPI.Comm,
    x: npt.NDArray[np.float64],
    background_x: npt.NDArray[np.float64],
    cells: npt.NDArray,
    sign: npt.NDArray[np.float64],
    moved: npt.NDArray[np.bool_],
) -> dict[str, float | int]:
    """The figures of :func:`quality_report` for given (owned) triangles (collective).

    Parameters
    ----------
    comm
        Communicator to reduce over.
    x, background_x
        Conforming and background vertex positions ``(num_vertices, 2)``.
    cells
        Owned triangles ``(m, 3)`` to report on.
    sign, moved
        Vertex signs and moved flags ``(num_vertices,)``.
    """
    ang = np.degrees(interior_angles(x, cells))
    inside = (sign[cells] < 0).sum(axis=1)
    Q = edge_ratio(x, cells)
    area0 = signed_areas(background_x, cells)
    area1 = signed_areas(x, cells)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = area1 / area0

    def red(value, op, empty):
        return comm.allreduce(value if len(cells) else empty, op=op)

    report: dict[str, float | int] = {
        "n_cells": red(len(cells), MPI.SUM, 0),
        "n_positively_cut": red(int(positively_cut(sign, cells).sum()), MPI.SUM, 0),
        "n_unaltered": red(int((~moved[cells].any(axis=1)).sum()), MPI.SUM, 0),
        "theta_min_deg": red(float(ang.min()) if len(cells) else 180.0, MPI.MIN, 180.0),
        "theta_max_deg": red(float(ang.max()) if len(cells) else 0.0, MPI.MAX, 0.0),
        "q_max": red(float(radius_ratio(x, cells).max()) if len(cells) else 0.0, MPI.MAX, 0.0),
    }
    for k in (3, 2, 1):
        sel = Q[inside == k]
        report[f"Q{k}_max"] = comm.allreduce(float(sel.max()) if len(sel) else 0.0, MPI.MAX)
    report["n_inverted"] = red(int((ratio <= 0).sum()), MPI.SUM, 0)
    report["min_area_ratio"] = red(float(ratio.min()) if len(cells) else np.inf, MPI.MIN, np.inf)
    report["percent_unaltered"] = 100.0 * report["n_unaltered"] / max(report["n_cells"], 1)
    return report
