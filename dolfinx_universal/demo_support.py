"""What every demo shares: options, rank-0 printing, and a summary with versions."""

from __future__ import annotations

import argparse
import json
import platform
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mpi4py import MPI

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from dolfinx import fem

__all__ = ["demo_options", "log", "point_values", "versions", "write_summary"]


def demo_options(
    description: str, default_out: str, argv: Sequence[str] | None = None
) -> argparse.Namespace:
    """Parse a demo's ``--quick`` and ``--out DIR`` (``argv=None``: the command line).

    Parameters
    ----------
    description
        Shown by ``--help``.
    default_out
        Output folder when ``--out`` is not given.
    argv
        Arguments; ``[]`` in notebooks and tests gives the defaults.
    """
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--quick", action="store_true", help="coarser study, same computation")
    p.add_argument("--out", type=Path, default=Path(default_out), help="output folder")
    return p.parse_args(argv)


def log(comm: MPI.Comm, *args: object) -> None:
    """``print`` on rank 0 only, flushed."""
    if comm.rank == 0:
        print(*args, flush=True)


def versions() -> dict[str, str]:
    """Versions of this package, DOLFINx, basix, UFL, PETSc, NumPy, MPI and Python."""
    from petsc4py import PETSc

    import basix
    import dolfinx
    import numpy as np
    import ufl

    from dolfinx_universal import __version__

    return {
        "dolfinx_universal": __version__,
        "dolfinx": dolfinx.__version__,
        "basix": basix.__version__,
        "ufl": ufl.__version__,
        "petsc": ".".join(str(v) for v in PETSc.Sys.getVersion()),
        "numpy": np.__version__,
        "mpi": MPI.Get_library_version().splitlines()[0].strip(),
        "python": platform.python_version(),
    }


def write_summary(
    comm: MPI.Comm,
    out: Path,
    results: dict[str, Any],
    *,
    parameters: dict[str, Any] | None = None,
    reference: dict[str, Any] | None = None,
    name: str = "summary.json",
) -> Path:
    """Write ``results`` with the run's parameters, reference values and versions (rank 0).

    The file holds the keys of ``results`` plus ``"parameters"`` (the set-up),
    ``"reference"`` (exact or published values the results are compared with),
    ``"versions"`` and ``"mpi_size"``. Collective (a barrier at the end).

    Returns
    -------
    The path written.
    """
    path = Path(out) / name
    error: str | None = None
    if comm.rank == 0:
        data = dict(results)
        data["parameters"] = parameters or {}
        data["reference"] = reference or {}
        data["versions"] = versions()
        data["mpi_size"] = comm.size
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(data, indent=2, allow_nan=False) + "\n")
        except (OSError, ValueError, TypeError) as e:  # raised on every rank below
            error = f"cannot write {path}: {e}"
    error = comm.bcast(error, root=0)
    if error is not None:
        raise OSError(error)
    return path


def point_values(
    functions: Sequence[fem.Function], points: npt.ArrayLike, cells: npt.ArrayLike | None = None
) -> list[npt.NDArray[np.float64]]:
    """Values of ``functions`` (on one mesh) at ``points (n, 3)``, the same on every rank
    (collective).

    Each point is evaluated by the lowest rank with a cell containing it among its owned
    ``cells`` (default: all owned cells), so each is counted once; points in no such cell
    of any rank are NaN.

    Returns
    -------
    For each function, ``(n, bs)`` values (``bs`` its value size).
    """
    from dolfinx import geometry

    msh = functions[0].function_space.mesh
    comm = msh.comm
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    owned = msh.topology.index_map(msh.topology.dim).size_local  # cells (not facets in 3D)
    cells = np.arange(owned) if cells is None else np.asarray(cells)
    tree = geometry.bb_tree(msh, msh.topology.dim, entities=cells[cells < owned].astype(np.int32))
    colliding = geometry.compute_colliding_cells(
        msh, geometry.compute_collisions_points(tree, points), points
    )
    found = np.diff(colliding.offsets) > 0
    taker = np.empty(len(points), dtype=np.int64)
    comm.Allreduce(np.where(found, comm.rank, comm.size).astype(np.int64), taker, op=MPI.MIN)
    take = np.flatnonzero(taker == comm.rank)
    first = colliding.array[colliding.offsets[take]]
    out = []
    for f in functions:
        values = np.zeros((len(points), int(np.prod(f.function_space.value_shape))))
        if len(take):
            values[take] = np.reshape(f.eval(points[take], first), (len(take), -1))
        total = np.empty_like(values)
        comm.Allreduce(values, total, op=MPI.SUM)
        total[taker == comm.size] = np.nan
        out.append(total)
    return out
