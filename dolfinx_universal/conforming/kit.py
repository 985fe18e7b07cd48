"""The per-dimension stages of conforming, picked by cell type: triangles (2D), tetrahedra (3D).

Every stage of :class:`~dolfinx_universal.conforming.universal.UniversalMesh` is one driver
for both dimensions; what differs per cell type is looked up here, from the background's
topological dimension: the cell geometry (:class:`~dolfinx_universal.cells.kit.CellKernels`)
and the stage functions of the ``*_tri`` and ``*_tet`` modules.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from dolfinx_universal.cells.kit import CellKernels, cell_kernels
from dolfinx_universal.conforming.relax_common import Relaxation
from dolfinx_universal.conforming.relax_tet import relax_tetrahedra
from dolfinx_universal.conforming.relax_tri import relax_triangles

__all__ = ["ConformingKit", "conforming_kit"]


@dataclass(frozen=True)
class ConformingKit:
    """What differs between conforming triangle and tetrahedron backgrounds."""

    cells: CellKernels
    """The cell geometry."""
    relax: Callable[..., Relaxation]
    """The vertex relaxation, with the arguments of
    :func:`~dolfinx_universal.conforming.relax.relax_vertices`."""


_KITS = {
    2: ConformingKit(cells=cell_kernels(2), relax=relax_triangles),
    3: ConformingKit(cells=cell_kernels(3), relax=relax_tetrahedra),
}


def conforming_kit(tdim: int) -> ConformingKit:
    """The stages of triangle (``tdim = 2``) or tetrahedron (``tdim = 3``) backgrounds."""
    return _KITS[cell_kernels(tdim).tdim]
