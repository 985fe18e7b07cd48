"""The per-dimension kernels the stages pick by cell type: triangles (2D) and tetrahedra (3D).

Every stage of the pipeline (classification, band and projection, perturbation, Gamma_h,
``M_h``, relaxation, checks, quality) is one function for both dimensions; what truly
differs per dimension (cell geometry, the angles that measure quality, the conditioning test,
the topology of Gamma_h) is looked up here from the background's topological dimension.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from dolfinx import mesh as dmesh

from dolfinx_universal.cells import tet, tri
from dolfinx_universal.core.arrays import Float, Int

__all__ = ["CellKernels", "cell_kernels"]


@dataclass(frozen=True)
class CellKernels:
    """What differs between triangle and tetrahedron backgrounds."""

    tdim: int
    """Topological (and geometric) dimension."""
    cell_type: dmesh.CellType
    """DOLFINx cell type."""
    name: str
    """Cell name in messages ("triangle", "tetrahedron")."""
    plural: str
    """Cell name in messages, plural ("triangles", "tetrahedra")."""
    facet_name: str
    """Facet name in messages ("edge", "face")."""
    signed_measures: Callable[[Float, Int], Float]
    """Signed areas or volumes ``(m,)`` of cells ``(m, tdim + 1)``, positive when
    positively oriented."""
    cell_diameters: Callable[[Float, Int], Float]
    """Longest edge of each cell ``(m,)``."""
    angles: Callable[[Float, Int], Float]
    """The angles that measure quality (radians): interior angles ``(m, 3)`` of triangles,
    dihedral angles ``(m, 6)`` of tetrahedra."""
    angle_name: str
    """The angle that measures quality in messages ("an angle", "a dihedral angle")."""
    barycentric: Callable[[Float, Int, Float], Float]
    """Barycentric coordinates ``(m, tdim)`` of vertices ``1 .. tdim`` of cells ``(m, tdim +
    1)`` at points ``(m, tdim)``."""
    locator_bin: float
    """Side of the bins of point location, in typical cell sizes (tetrahedra: 2, at most 2
    bins per axis for most cells, where 3 per axis would mean up to 27 entries)."""
    max_min_angle: float
    """Smallest angle (degrees) of the regular cell: the largest sensible quality floor."""
    inward_push: bool
    """Whether ``M_h`` pushes the band's inside vertices inwards by up to ``alpha h``
    (triangles: Rangarajan & Lew 2014). Tetrahedra: ``M_h`` only snaps the vertices of the
    positive faces; pushing the others as well inverts tetrahedra where Gamma curves
    within a few ``h`` (a torus tube 1.4 h thick, a body of radius 2 h), and the vertex
    relaxation moves them afterwards."""


_TRIANGLES = CellKernels(
    tdim=2,
    cell_type=dmesh.CellType.triangle,
    name="triangle",
    plural="triangles",
    facet_name="edge",
    signed_measures=tri.signed_areas,
    cell_diameters=tri.cell_diameters,
    angles=tri.interior_angles,
    angle_name="an angle",
    barycentric=tri.barycentric,
    locator_bin=1.0,
    max_min_angle=60.0,
    inward_push=True,
)


_TETRAHEDRA = CellKernels(
    tdim=3,
    cell_type=dmesh.CellType.tetrahedron,
    name="tetrahedron",
    plural="tetrahedra",
    facet_name="face",
    signed_measures=tet.signed_volumes,
    cell_diameters=tet.cell_diameters,
    angles=tet.dihedral_angles,
    angle_name="a dihedral angle",
    barycentric=tet.barycentric,
    locator_bin=2.0,
    max_min_angle=float(np.degrees(np.arccos(1.0 / 3.0))),
    inward_push=False,
)

_KITS = {2: _TRIANGLES, 3: _TETRAHEDRA}


def cell_kernels(tdim: int) -> CellKernels:
    """The kernels of triangle (``tdim = 2``) or tetrahedron (``tdim = 3``) meshes."""
    kit = _KITS.get(tdim)
    if kit is None:
        raise ValueError(f"universal meshes are triangle or tetrahedron meshes, got tdim = {tdim}")
    return kit
