"""The per-dimension stages of conforming, picked by cell type: triangles (2D), tetrahedra (3D).

Every stage of :class:`~dolfinx_universal.conforming.universal.UniversalMesh` is one driver
for both dimensions; what differs per cell type is looked up here, from the background's
topological dimension: the cell geometry (:class:`~dolfinx_universal.cells.kit.CellKernels`)
and the stage functions of the ``*_tri`` and ``*_tet`` modules.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from dolfinx_universal.cells.kit import CellKernels, cell_kernels
from dolfinx_universal.conforming import (
    checks,
    checks_tet,
    checks_tri,
    quality_tet,
    quality_tri,
    snap,
)
from dolfinx_universal.conforming.relax_common import Relaxation
from dolfinx_universal.conforming.relax_tet import relax_tetrahedra
from dolfinx_universal.conforming.relax_tri import relax_triangles

__all__ = ["ConformingKit", "conforming_kit"]


@dataclass(frozen=True)
class ConformingKit:
    """What differs between conforming triangle and tetrahedron backgrounds."""

    cells: CellKernels
    """The cell geometry."""
    eager_facets: bool
    """Whether the background's facets are built when it is prepared (triangles), or at the
    first conform (tetrahedra: DOLFINx's faces of 1e6 tetrahedra take seconds, and its first
    ``create_submesh`` builds them anyway)."""
    band: Callable[..., snap.Band]
    """The cells at the band, ``(topology, c2v, band, s, num_owned_cells) -> Band``
    (:func:`~dolfinx_universal.conforming.snap.triangle_band`,
    :func:`~dolfinx_universal.conforming.snap.tetrahedron_band`)."""
    perturbation_candidates: Callable[..., Any]
    """The vertices the eta perturbation relocates (the ``candidates`` of
    :func:`~dolfinx_universal.conforming.snap.perturb`)."""
    repair: Callable[..., tuple[snap.PositiveFacets, int]]
    """The repair of Gamma_h after the perturbation, with the arguments of
    :func:`~dolfinx_universal.conforming.snap.tetrahedron_repair` (tetrahedra: the interior
    faces with three vertices outside; triangles: none)."""
    conditioning: Callable[..., tuple[float, Any]]
    """The conditioning test of the positively cut cells, ``(xp, x0, phi, facets) ->
    (largest angle, problem or None)``."""
    open_chains: Callable[..., Any]
    """Vertices of Gamma_h with a wrong number of positive facets, from the counts."""
    sample_gamma: Callable[..., Any]
    """Samples of Gamma for the containment and Gamma_h checks, ``(comm, boundary,
    spacing) -> samples`` with their ``points``."""
    sample_spacing: float
    """The spacing of those samples, in units of the smallest mesh size at Gamma."""
    containment: Callable[..., Any]
    """The containment check, built once per background from ``(x, c2v)``: its
    ``problems(comm, pts, phi, h, near_cells, near_cv, v2c)``."""
    topology_problems: Callable[..., tuple[list, int, int]]
    """The topology check of Gamma_h, ``(comm, gids, xp, facets, samples, far_kept) ->
    (problems, closed parts, kept pieces)``."""
    measures: Callable[..., checks.TetMeasures | None]
    """What the output checks measure of the moved cells, computed once for the inversion
    and quality checks, ``(x, y, moved, cells)``
    (:func:`~dolfinx_universal.conforming.checks.tet_measures`; None for triangles)."""
    shape_figures: Callable[..., dict[str, Any]]
    """The quality figures of the cells in
    :func:`~dolfinx_universal.conforming.quality.quality_report`, ``(comm, x, background_x,
    cells, sign) -> figures`` (collective)."""
    relax: Callable[..., Relaxation]
    """The vertex relaxation, with the arguments of
    :func:`~dolfinx_universal.conforming.relax.relax_vertices`."""


_KITS = {
    2: ConformingKit(
        cells=cell_kernels(2),
        eager_facets=True,
        band=snap.triangle_band,
        perturbation_candidates=snap.triangle_candidates,
        repair=snap.triangle_repair,
        conditioning=checks_tri.conditioning_problem,
        open_chains=checks_tri.open_chains,
        sample_gamma=checks_tri.sample_gamma,
        sample_spacing=0.25,
        containment=checks_tri.Containment,
        topology_problems=checks_tri.topology_problems,
        measures=checks_tri.no_measures,
        shape_figures=quality_tri.shape_figures,
        relax=relax_triangles,
    ),
    3: ConformingKit(
        cells=cell_kernels(3),
        eager_facets=False,
        band=snap.tetrahedron_band,
        perturbation_candidates=snap.tetrahedron_candidates,
        repair=snap.tetrahedron_repair,
        conditioning=checks_tet.conditioning_problem,
        open_chains=checks_tet.open_chains,
        sample_gamma=checks_tet.sample_gamma,
        sample_spacing=0.5,
        containment=checks_tet.Containment,
        topology_problems=checks_tet.topology_problems,
        measures=checks.tet_measures,
        shape_figures=quality_tet.shape_figures,
        relax=relax_tetrahedra,
    ),
}


def conforming_kit(tdim: int) -> ConformingKit:
    """The stages of triangle (``tdim = 2``) or tetrahedron (``tdim = 3``) backgrounds."""
    return _KITS[cell_kernels(tdim).tdim]
