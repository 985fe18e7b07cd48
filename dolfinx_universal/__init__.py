"""Universal meshes for DOLFINx: conform one background mesh to curved and moving domains."""

try:  # the PyPI wheel of DOLFINx must be initialised before dolfinx/petsc4py are imported
    import dolfinx_solver  # noqa: F401
except ImportError:  # DOLFINx from the official Docker images or conda
    pass

from importlib.metadata import PackageNotFoundError, version

from . import io
from .background import equilateral_mesh, refine_uniform
from .background_tet import a15_mesh, bcc_mesh
from .boundaries import (
    Boundary,
    Circle,
    Domain,
    Ellipse,
    ImplicitCurve,
    PeriodicSpline,
    PolarCurve,
    RigidMotion,
)
from .classify import conditioning_angle, positive_edges, positively_cut
from .conform import IMMERSED, OUTER, ConformingMesh, UniversalMesh, conform
from .constraints import SlipConstraint
from .curved import CurvedMesh, boundary_dof_data, curved_mesh
from .domain import Certificate, MeshedDomain, mesh_domain
from .graded import graded_mesh
from .graded_tet import graded_tet_mesh
from .moving import MovingDomain
from .moving_problem import MovingLinearProblem, MovingStokes
from .quality import quality_report
from .relax import relax_vertices
from .sizing import box_size, mark_cells, refine_size, threshold
from .surfaces import Ellipsoid, ImplicitSurface, Sphere, Surface, Torus
from .validation import MeshingError

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
