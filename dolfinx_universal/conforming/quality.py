"""Quality of conforming meshes: angles, radius ratios, edge ratios, what was altered.

One report for both dimensions (:func:`quality_report`): the counts of cells kept, cut and
unaltered are common; the shape figures are those of the cells, picked by the number of
vertices per cell: interior angles, radius ratios and edge ratios of triangles; dihedral
angles, radius and mean ratios of tetrahedra
(:func:`~dolfinx_universal.cells.tet.quality_summary`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from dolfinx_universal.cells import tet as _tetrahedron
from dolfinx_universal.cells.tri import edge_lengths, signed_areas, triangle_measures
from dolfinx_universal.conforming.classify import positively_cut
from dolfinx_universal.core.arrays import any_rows

if TYPE_CHECKING:
    from dolfinx_universal.conforming.universal import ConformingMesh

__all__ = ["background_positions", "cell_quality", "edge_ratio", "quality_report", "radius_ratio"]

QualityReport = dict[str, Any]
"""The figures of :func:`quality_report`: ints and floats (and, for tetrahedra, the
dihedral angle histogram as a list of ints)."""


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


def quality_report(cm: ConformingMesh) -> QualityReport:
    """Global quality figures of a conforming mesh (collective).

    Returns
    -------
    A dict with, in both dimensions: ``n_cells`` (cells kept), ``n_positively_cut``,
    ``n_unaltered`` (no vertex moved), ``percent_unaltered``, ``theta_min_deg`` and
    ``theta_max_deg`` (smallest and largest angle: interior angles of triangles, dihedral
    angles of tetrahedra) and ``n_inverted`` (cells whose orientation differs from that of
    the cell in the original background: the relaxation may move ``background_x`` of the
    vertices on Gamma, the orientation is checked against the background itself).

    Triangles add ``q_max`` (max circumradius/inradius), ``Q3_max``, ``Q2_max``, ``Q1_max``
    (max longest/shortest edge over triangles with 3, 2 and 1 vertices inside the domain; 0
    when there are none) and ``min_area_ratio`` (conforming area over the area of the
    triangle in the background).

    Tetrahedra add ``dihedral_histogram`` (counts of the dihedral angles in the 18 bins of
    10 degrees over [0, 180], a list of ints), ``radius_ratio_min`` (``3 r_in / R_circ``, 1
    for the regular tetrahedron), ``mean_ratio_min`` (signed by the background's orientation)
    and ``min_volume_ratio`` (conforming volume over the background tetrahedron's volume).
    """
    nco = cm.mesh.topology.index_map(cm.mesh.topology.dim).size_local
    return cell_quality(
        cm.mesh.comm, cm.x, background_positions(cm), cm.cells[:nco], cm.sign, cm.moved
    )


def background_positions(cm: ConformingMesh) -> npt.NDArray[np.float64]:
    """Original background positions of the vertices of ``cm``, ``(num_vertices, tdim)``."""
    bg = cm.background
    topo = bg.topology
    tdim = topo.dim
    topo.create_connectivity(tdim, 0)
    c2v = topo.connectivity(tdim, 0).array.reshape(-1, tdim + 1)
    imv = topo.index_map(0)
    v2n = np.empty(imv.size_local + imv.num_ghosts, dtype=np.int32)
    v2n[c2v] = bg.geometry.dofmaps[0][:, : tdim + 1]
    return bg.geometry.x[v2n[cm.vertex_map], :tdim]


def cell_quality(
    comm: MPI.Comm,
    x: npt.NDArray[np.float64],
    background_x: npt.NDArray[np.float64],
    cells: npt.NDArray,
    sign: npt.NDArray[np.float64],
    moved: npt.NDArray[np.bool_],
) -> QualityReport:
    """The figures of :func:`quality_report` for given (owned) cells (collective).

    Parameters
    ----------
    comm
        Communicator to reduce over.
    x, background_x
        Conforming and background vertex positions ``(num_vertices, tdim)``.
    cells
        Owned triangles ``(m, 3)`` or tetrahedra ``(m, 4)`` to report on (every rank
        passes cells of one kind, possibly none).
    sign, moved
        Vertex signs and moved flags ``(num_vertices,)``.
    """
    cells = np.asarray(cells)
    shape = _tetrahedra if cells.shape[1] == 4 else _triangles
    report = {
        "n_cells": comm.allreduce(len(cells), op=MPI.SUM),
        "n_positively_cut": comm.allreduce(int(positively_cut(sign, cells).sum()), op=MPI.SUM),
        "n_unaltered": comm.allreduce(int((~any_rows(moved[cells])).sum()), op=MPI.SUM),
    }
    report.update(shape(comm, x, background_x, cells, sign))
    report["percent_unaltered"] = 100.0 * report["n_unaltered"] / max(report["n_cells"], 1)
    return report


def _triangles(
    comm: MPI.Comm,
    x: npt.NDArray[np.float64],
    background_x: npt.NDArray[np.float64],
    cells: npt.NDArray,
    sign: npt.NDArray[np.float64],
) -> QualityReport:
    """Angle, radius ratio, edge ratio and area figures of triangles (reduced)."""
    rad, e, area1 = triangle_measures(x, cells)  # one gather; e for both ratios
    ang = np.degrees(rad)
    neg = sign[cells] < 0
    inside = neg[:, 0].astype(np.int8) + neg[:, 1] + neg[:, 2]  # vertices inside, by columns
    Q = _edge_ratio(e)
    area0 = signed_areas(background_x, cells)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = area1 / area0

    def red(value, op, empty):
        return comm.allreduce(value if len(cells) else empty, op=op)

    report: QualityReport = {
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


def _tetrahedra(
    comm: MPI.Comm,
    x: npt.NDArray[np.float64],
    background_x: npt.NDArray[np.float64],
    cells: npt.NDArray,
    sign: npt.NDArray[np.float64],
) -> QualityReport:
    """Dihedral angle, radius ratio, mean ratio and volume figures of tetrahedra (reduced).

    Orientation and volume ratio are taken against the background tetrahedra (DOLFINx
    does not orient tetrahedra, so either sign is valid there)."""
    vol0 = _tetrahedron.signed_volumes(background_x, cells)
    s, vol1 = _tetrahedron.summary_and_volumes(x, cells, np.where(vol0 < 0, -1.0, 1.0))
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
