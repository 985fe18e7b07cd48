"""Errors raised on every rank together, and MPI reductions of per-vertex data."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any, TypeVar

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import la

__all__ = ["MeshingError", "collective_call", "raise_collective", "vertex_reduce", "where"]

T = TypeVar("T")


class MeshingError(RuntimeError):
    """The domain cannot be meshed on this background; the message says where and what to do."""


def where(points: npt.ArrayLike, limit: int = 3) -> str:
    """Format up to ``limit`` points as ``(x, y)`` for error messages."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, np.shape(points)[-1])[:, :2]
    text = ", ".join(f"({a:.6g}, {b:.6g})" for a, b in p[:limit])
    return text + (f" and {len(p) - limit} more" if len(p) > limit else "")


def raise_collective(
    comm: MPI.Comm, problems: Iterable[str], error: type[Exception] = MeshingError
) -> None:
    """Raise ``error`` on every rank if any rank reports a problem; otherwise return.

    Each rank passes its own (possibly empty) list of messages. This is a collective call:
    every rank must call it, so that no rank is left waiting in a later collective.
    """
    local = list(problems)[:5]
    found = [m for msgs in comm.allgather(local) for m in msgs]
    if found:
        unique = list(dict.fromkeys(found))
        raise error("\n".join(unique[:5]))


def collective_call(comm: MPI.Comm, what: str, fn: Callable[..., T], *args: Any) -> T:
    """Call ``fn(*args)`` on every rank; if it raises on any rank, raise on all of them.

    User callbacks (boundaries) may fail on the points of one rank only; raising there alone
    would leave the other ranks waiting in the next collective call.
    """
    try:
        result, problems = fn(*args), []
    except (ValueError, RuntimeError, ArithmeticError) as e:
        result, problems = None, [f"{what} failed: {e}"]
    raise_collective(comm, problems)
    return result  # type: ignore[return-value]


def vertex_reduce(
    index_map, values: npt.ArrayLike, op: str = "sum"
) -> npt.NDArray[np.float64]:
    """Combine per-vertex contributions of all ranks, owned and ghost entries alike.

    Parameters
    ----------
    index_map
        Vertex index map of the mesh (``topology.index_map(0)``).
    values
        Local contributions, ``(size_local + num_ghosts,)``.
    op
        ``"sum"`` or ``"max"``.

    Returns
    -------
    The reduced values on owned and ghost vertices, ``(size_local + num_ghosts,)``.
    """
    values = np.asarray(values, dtype=np.float64)
    if index_map.comm.size == 1:
        return values.copy()
    from petsc4py import PETSc

    vec = la.vector(index_map, 1, dtype=np.float64)
    vec.array[:] = values
    pv = vec.petsc_vec
    mode = {"sum": PETSc.InsertMode.ADD_VALUES, "max": PETSc.InsertMode.MAX_VALUES}[op]
    pv.ghostUpdate(addv=mode, mode=PETSc.ScatterMode.REVERSE)
    pv.ghostUpdate(addv=PETSc.InsertMode.INSERT_VALUES, mode=PETSc.ScatterMode.FORWARD)
    out = vec.array.copy()
    return out
