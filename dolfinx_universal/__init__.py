"""Universal meshes for DOLFINx: conform one background mesh to curved and moving domains."""

try:  # the PyPI wheel of DOLFINx must be initialised before dolfinx/petsc4py are imported
    import dolfinx_solver  # noqa: F401
except ImportError:  # DOLFINx from the official Docker images or conda
    pass

from importlib.metadata import PackageNotFoundError, version

from dolfinx_universal import io
from dolfinx_universal.backgrounds.graded_tet import graded_tet_mesh
from dolfinx_universal.backgrounds.graded_tri import graded_mesh
from dolfinx_universal.backgrounds.lattice_tet import a15_mesh, bcc_mesh
from dolfinx_universal.backgrounds.lattice_tri import equilateral_mesh, refine_uniform
from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.boundaries.curves import (
    Circle,
    Ellipse,
    ImplicitCurve,
    PeriodicSpline,
    PolarCurve,
)
from dolfinx_universal.boundaries.domains import Domain
from dolfinx_universal.boundaries.motions import RigidMotion
from dolfinx_universal.boundaries.surfaces import (
    Ellipsoid,
    ImplicitSurface,
    Sphere,
    Surface,
    Torus,
)
from dolfinx_universal.conforming.classify import conditioning_angle, positive_edges, positively_cut
from dolfinx_universal.conforming.quality import quality_report
from dolfinx_universal.conforming.relax import relax_vertices
from dolfinx_universal.conforming.universal import (
    IMMERSED,
    OUTER,
    ConformingMesh,
    UniversalMesh,
    conform,
)
from dolfinx_universal.core.collective import MeshingError
from dolfinx_universal.curved.constraints import SlipConstraint
from dolfinx_universal.curved.maps import CurvedMesh, boundary_dof_data, curved_mesh
from dolfinx_universal.meshing.domain import Certificate, MeshedDomain, mesh_domain
from dolfinx_universal.moving.domain import MovingDomain
from dolfinx_universal.moving.problems import MovingLinearProblem, MovingStokes
from dolfinx_universal.moving.stepping import TimeStepper
from dolfinx_universal.sizing.fields import box_size, mark_cells, refine_size, threshold

try:
    __version__ = version("dolfinx_universal")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0"

__all__ = [
    "IMMERSED",
    "OUTER",
    "Boundary",
    "Certificate",
    "Circle",
    "ConformingMesh",
    "CurvedMesh",
    "Domain",
    "Ellipse",
    "Ellipsoid",
    "ImplicitCurve",
    "ImplicitSurface",
    "MeshedDomain",
    "MeshingError",
    "MovingDomain",
    "MovingLinearProblem",
    "MovingStokes",
    "PeriodicSpline",
    "PolarCurve",
    "RigidMotion",
    "SlipConstraint",
    "Sphere",
    "Surface",
    "TimeStepper",
    "Torus",
    "UniversalMesh",
    "a15_mesh",
    "bcc_mesh",
    "boundary_dof_data",
    "box_size",
    "conditioning_angle",
    "conform",
    "curved_mesh",
    "equilateral_mesh",
    "graded_mesh",
    "graded_tet_mesh",
    "io",
    "mark_cells",
    "mesh_domain",
    "positive_edges",
    "positively_cut",
    "quality_report",
    "refine_size",
    "refine_uniform",
    "relax_vertices",
    "threshold",
]
