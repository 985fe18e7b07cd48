"""Validity checks of a conforming mesh: classification, containment, Gamma_h, output, quality."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

from dolfinx_universal.cells.kit import cell_kernels
from dolfinx_universal.cells.tet import EDGES, soa_corners, soa_det6, soa_dihedral, soa_sq, soa_sub
from dolfinx_universal.conforming.checks_tri import gamma_h_topology
from dolfinx_universal.conforming.locate import (
    CONTAINMENT_SAMPLES,
    CellLocator,
    cells_near_points,
    containment_problems,
    containment_samples,
    missing_samples_problems,
    points_in_cells,
    samples_in_stars,
)
from dolfinx_universal.conforming.messages import TOPOLOGY_MESSAGES, TopologyMessages
from dolfinx_universal.core.arrays import Bool, Float, Int
from dolfinx_universal.core.collective import MeshingError, Problem, collective_call

if TYPE_CHECKING:
    from dolfinx_universal.boundaries.base import Boundary
    from dolfinx_universal.conforming.kit import ConformingKit
    from dolfinx_universal.conforming.snap import PositiveFacets

__all__ = [
    "CONTAINMENT_SAMPLES",
    "TOPOLOGY_MESSAGES",
    "CellLocator",
    "TetMeasures",
    "TopologyMessages",
    "cells_near_points",
    "classification_problems",
    "conforming_problems",
    "containment_problems",
    "containment_samples",
    "gamma_h_topology",
    "low_quality_cells",
    "missing_samples_problems",
    "points_in_cells",
    "require_kept",
    "samples_in_stars",
    "tet_measures",
]


def require_kept(comm: MPI.Comm, kept_owned: Bool, boundary: Boundary) -> None:
    """Raise unless some rank keeps a cell, i.e. some background vertex lies inside (collective).

    Parameters
    ----------
    comm
        Communicator of the mesh.
    kept_owned
        Kept flags of this rank's owned cells ``(num_owned_cells,)``.
    boundary
        The domain (sampled for the places of the error).

    Raises
    ------
    MeshingError
        On every rank, when no rank keeps a cell.
    """
    if comm.allreduce(int(np.count_nonzero(kept_owned))) == 0:
        raise MeshingError(
            "no background vertex lies inside the domain: the domain is outside the "
            "background mesh or smaller than its triangles; move or refine the background",
            collective_call(comm, "sampling the boundary", boundary.sample, 64),
        )


def classification_problems(
    kit: ConformingKit,
    xp: Float,
    s: Float,
    phi: Float,
    edges: PositiveFacets,
    c2v: Int,
    c2f: Int,
    f2c_offsets: Int,
    f2c: Int,
    num_owned_vertices: int,
    x0: Float | None = None,
) -> tuple[list[Problem], float]:
    """Local problems with the classification: the conditions of the method.

    Parameters
    ----------
    kit
        The stages of the background's cell type
        (:func:`~dolfinx_universal.conforming.kit.conforming_kit`).
    xp, s, phi
        Perturbed vertex positions ``(num_vertices, gdim)``, final signs and signed distances
        ``(num_vertices,)``.
    edges
        Positive edges and incidence counts (:func:`~dolfinx_universal.conforming.snap.gamma_h`).
    c2v, c2f
        Cell -> vertex and cell -> facet connectivity of the background ``(num_cells, 3)``.
    f2c_offsets, f2c
        Facet -> cell adjacency list (offsets ``(num_facets + 1,)`` and cells).
    num_owned_vertices
        Number of owned vertices (the first ones).
    x0
        Unperturbed background positions (tetrahedra: the conditioning test is a property
        of the background cells); ``xp`` if None.

    Returns
    -------
    problems
        This rank's problems.
    theta_max
        The largest conditioning angle (radians, 0 without positively cut cells).
    """
    pc_owned = edges.cells
    cells, facet = kit.cells.plural, kit.cells.facet_name
    problems = []
    theta_max = 0.0
    if len(pc_owned):
        theta_max, problem = kit.conditioning(xp, xp if x0 is None else x0, phi, edges)
        if problem is not None:
            problems.append(problem)

        # The positive facet is the facet opposite the inside vertex.
        def centre(rows: npt.NDArray[np.intp]) -> Float:
            return xp[edges.facets[rows]].mean(axis=1)

        k = np.argmin(s[c2v[pc_owned]], axis=1)
        f = c2f[pc_owned, k]
        off = f2c_offsets
        ncell = off[f + 1] - off[f]
        lone = ncell == 1
        if lone.any():
            problems.append(
                Problem(
                    "the domain reaches the boundary of the background mesh near {where}: "
                    "enlarge the background",
                    centre(np.flatnonzero(lone)),
                    int(lone.sum()),
                    refinable=False,
                )
            )
        two = np.flatnonzero(ncell == 2)
        c0, c1 = f2c[off[f[two]]], f2c[off[f[two]] + 1]
        other = np.where(c0 == pc_owned[two], c1, c0)
        shared = two[edges.kept[other]]
        if len(shared):
            problems.append(
                Problem(
                    f"Gamma crosses both {cells} beside the positive {facet} near {{where}} (a "
                    "thin part of the domain or of its exterior): the background is too "
                    "coarse there, refine near it",
                    centre(shared),
                    len(shared),
                )
            )
    nvo = num_owned_vertices
    count, in_kept = edges.count[:nvo], edges.in_kept[:nvo]
    # Triangles: two positive edges at every vertex of Gamma_h (closed simple curves); the
    # surface of positive faces (tetrahedra) is checked by checks_tet.surface_topology.
    chain = kit.open_chains(count)
    lost = in_kept & (s[:nvo] > 0) & (count == 0)
    for bad, text in (
        (
            chain,
            "Gamma_h (the union of positive edges) is not a set of closed simple curves at "
            "vertices {where}: the background is too coarse for the boundary's curvature "
            "or for the gap between its parts there; refine near them",
        ),
        (
            lost,
            f"vertices outside the domain at {{where}} belong to kept {cells} but to no "
            f"positive {facet}, so they would not be snapped: Gamma is under-resolved there; "
            "refine the background near them",
        ),
    ):
        if bad.any():
            problems.append(Problem(text, xp[:nvo][bad], int(bad.sum())))
    return problems, theta_max


class TetMeasures(NamedTuple):
    """What the output checks measure of the moved tetrahedra, computed once
    (:func:`tet_measures`) for :func:`conforming_problems` and :func:`low_quality_cells`."""

    cells: Int
    """The moved cells ``(m, 4)``."""
    volume0: Float
    """Signed volumes in the background ``(m,)``."""
    volume: Float
    """Signed volumes of the images ``(m,)``."""
    diameter0: Float
    """Longest edges in the background ``(m,)``."""
    angles: Float
    """Dihedral angles (radians) of the images ``(m, 6)``."""


def tet_measures(x: Float, y: Float, moved: Bool, cells: Int) -> TetMeasures:
    """Volumes, diameters and dihedral angles of the moved tetrahedra among ``cells``.

    The arithmetic of :func:`~dolfinx_universal.cells.tet.signed_volumes`,
    :func:`~dolfinx_universal.cells.tet.cell_diameters` and
    :func:`~dolfinx_universal.cells.tet.dihedral_angles` (bitwise the same values), in
    one pass: the moved cells selected once, each corner gathered once per position array,
    and the images' volumes shared by the inversion test and the angles.

    Parameters
    ----------
    x, y
        Background vertex positions and their images ``(num_vertices, 3)``.
    moved
        Vertices whose image differs from their position ``(num_vertices,)``.
    cells
        Kept tetrahedra that may have moved ``(k, 4)``.
    """
    mv = moved[cells[:, 0]]
    for k in range(1, 4):
        mv |= moved[cells[:, k]]
    cells = cells[mv]
    q, p = soa_corners(x, cells), soa_corners(y, cells)
    d2 = np.zeros(len(cells))
    for i, j in EDGES:  # the longest edge, by squared lengths (sqrt is monotone)
        np.maximum(d2, soa_sq(soa_sub(q[j], q[i])), out=d2)
    v6 = soa_det6(p)
    angles = soa_dihedral(p, v6)
    return TetMeasures(cells, soa_det6(q) / 6.0, v6 / 6.0, np.sqrt(d2), angles)


def conforming_problems(
    x: Float,
    y: Float,
    moved: Bool,
    cells: Int,
    in_kept: Bool,
    outer_vertices: Int,
    measures: TetMeasures | None = None,
) -> list[Problem]:
    """Local problems with the conforming triangles: inversion, degeneracy, moved outer boundary.

    Parameters
    ----------
    x, y
        Background vertex positions and their images ``M_h(x)`` ``(num_vertices, 2)``.
    moved
        Vertices whose image differs from their position ``(num_vertices,)``.
    cells
        Kept triangles that may have moved (those near Gamma) ``(m, 3)``.
    in_kept
        Vertices of kept triangles near Gamma ``(num_vertices,)``.
    outer_vertices
        Vertices on the boundary of the background ``(k,)``.
    measures
        Tetrahedra: :func:`tet_measures` of ``cells``, if computed already.

    Returns
    -------
    This rank's problems.
    """
    problems = []
    k = cell_kernels(cells.shape[1] - 1)
    if measures is not None:
        cells, a0, a1, d = measures[:4]
    else:
        cells = cells[moved[cells].any(axis=1)]  # unmoved cells keep their shape
        a0, a1 = k.signed_measures(x, cells), k.signed_measures(y, cells)
        d = k.cell_diameters(x, cells)
    # degenerate: measure below 1e-10 of the diameter's square or cube (relative)
    inverted = (np.sign(a1) != np.sign(a0)) | (np.abs(a1) <= 1e-10 * d**k.tdim)
    if inverted.any():
        centre = y[cells[inverted]].mean(axis=1)
        problems.append(
            Problem(
                f"{{count}} conforming {k.plural} would be inverted or degenerate near {{where}}: "
                "the background is too coarse or not acute there; refine near those points "
                "or use an acute (e.g. equilateral or A15) background",
                centre,
                int(inverted.sum()),
            )
        )
    ev = outer_vertices
    shifted = ev[in_kept[ev] & moved[ev]]
    if len(shifted):
        problems.append(
            Problem(
                "the boundary of the background mesh would move at {where}: Gamma comes "
                "within R_r of it there; enlarge the background or reduce R_r",
                x[shifted],
                len(shifted),
                refinable=False,
            )
        )
    return problems


def low_quality_cells(
    y: Float, cells: npt.NDArray, min_angle_deg: float, angles: Float | None = None
) -> tuple[Problem | None, float, float]:
    """Conforming cells whose smallest angle (dihedral angle in 3D) is below a floor.

    Parameters
    ----------
    y
        Vertex positions of the conforming mesh ``(num_vertices, gdim)``.
    cells
        Cells to check ``(m, tdim + 1)`` (the moved ones: the others keep the background's
        angles).
    min_angle_deg
        The floor in degrees (0 disables the check).
    angles
        The cells' angles in radians, if computed already (:func:`tet_measures`).

    Returns
    -------
    problem
        A report of the cells below the floor, or None.
    theta_min, theta_max
        Smallest and largest angle (degrees) of these cells (180 and 0 when there are none).
    """
    if len(cells) == 0:
        return None, 180.0, 0.0
    k = cell_kernels(cells.shape[1] - 1)
    ang = np.degrees(k.angles(y, cells) if angles is None else angles)
    small = ang[:, 0].copy()  # column by column: reductions along a short axis are slow
    for j in range(1, ang.shape[1]):
        np.minimum(small, ang[:, j], out=small)
    lo, hi = float(small.min()), float(ang.max())
    bad = small < min_angle_deg
    if not bad.any():
        return None, lo, hi
    problem = Problem(
        f"{{count}} conforming {k.plural} have {k.angle_name} below the quality floor of "
        f"{min_angle_deg:g} degrees near {{where}}: refine the background there (or lower "
        "min_angle)",
        y[cells[bad]].mean(axis=1),
        int(bad.sum()),
    )
    return problem, lo, hi
