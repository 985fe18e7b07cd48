"""Errors raised on every rank together, and MPI reductions of per-vertex data."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any, NamedTuple, TypeVar

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
from dolfinx import la

__all__ = [
    "MeshingError",
    "Problem",
    "collective_call",
    "raise_collective",
    "vertex_reduce",
    "where",
]

T = TypeVar("T")


class MeshingError(RuntimeError):
    """The domain cannot be meshed on this background; the message says where and what to do.

    Parameters
    ----------
    message
        What is wrong, where, and what to do.
    points
        Places of the problem ``(n, 2)`` (the same on every rank when raised collectively):
        where :func:`~dolfinx_universal.meshing.domain.mesh_domain` refines the background.
    refinable
        False when no background size can fix the problem (e.g. the domain leaves the box).
    """

    def __init__(
        self, message: str, points: npt.ArrayLike | None = None, refinable: bool = True
    ) -> None:
        super().__init__(message)
        self.points = np.zeros((0, 2)) if points is None else np.asarray(points, float)
        self.refinable = bool(refinable)


def _rows(points: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Points as rows ``(n, d)``: 2D points keep 2 columns, 3D points 3 (an empty array or a
    flat one is read as 2D points)."""
    p = np.asarray(points, dtype=np.float64)
    d = p.shape[-1] if p.ndim >= 2 and p.shape[-1] in (2, 3) else 2
    return p.reshape(-1, d)


def where(points: npt.ArrayLike, limit: int = 3) -> str:
    """Format up to ``limit`` points as ``(x, y)`` or ``(x, y, z)`` for error messages."""
    p = _rows(points)
    text = ", ".join("(" + ", ".join(f"{c:.6g}" for c in q) + ")" for q in p[:limit])
    return text + (f" and {len(p) - limit} more" if len(p) > limit else "")


class Problem(NamedTuple):
    """One rank's report of a problem: a message template, the places and their count.

    ``message`` may contain ``{count}`` (replaced by the global count) and ``{where}``
    (replaced by up to three of the places of all ranks), so that the ranks' reports of one
    kind merge into one message.
    """

    message: str
    points: npt.NDArray[np.float64] = np.zeros((0, 2))
    count: int = 1  # type: ignore[assignment]  # field shadows tuple.count (legal at runtime)
    refinable: bool = True


def _literal(message: str) -> str:
    """A message as a template that formats to itself."""
    return message.replace("{", "{{").replace("}", "}}")


def raise_collective(
    comm: MPI.Comm,
    problems: Iterable[str | Problem],
    error: type[Exception] = MeshingError,
) -> None:
    """Raise ``error`` on every rank if any rank reports a problem; otherwise return.

    Each rank passes its own (possibly empty) list of problems: plain messages or
    :class:`Problem` records. Records with the same message template are merged over the
    ranks (counts added, places concatenated in rank order). This is a collective call:
    every rank must call it, so that no rank is left waiting in a later collective.
    """
    local = [
        p if isinstance(p, Problem) else Problem(_literal(p), np.zeros((0, 2)), 0) for p in problems
    ]
    # The common case, no problem anywhere, costs one integer reduction, not a gather.
    if comm.size > 1 and comm.allreduce(len(local), op=MPI.MAX) == 0:
        return
    gathered = comm.allgather([(p.message, _rows(p.points), p.count, p.refinable) for p in local])
    merged: dict[str, list] = {}
    for msgs in gathered:
        for message, pts, count, refinable in msgs:
            entry = merged.setdefault(message, [[], 0, True])
            entry[0].append(pts)
            entry[1] += count
            entry[2] &= refinable
    if not merged:
        return
    texts, points, refinable = [], [], True
    for message, (pts, count, ref) in list(merged.items())[:5]:
        p = _merge(pts)
        texts.append(message.format(count=count, where=where(p)))
        points.append(p)
        refinable &= ref
    text = "\n".join(texts)
    if issubclass(error, MeshingError):
        raise error(text, _merge(points), refinable)
    raise error(text)


def _merge(parts: list[npt.NDArray[np.float64]]) -> npt.NDArray[np.float64]:
    """Concatenate the non-empty point arrays (all of one dimension), ``(0, 2)`` if none."""
    full = [p for p in parts if len(p)]
    return np.concatenate(full) if full else np.zeros((0, 2))


def collective_call(
    comm: MPI.Comm,
    what: str,
    fn: Callable[..., T],
    *args: Any,
    error: type[Exception] = MeshingError,
) -> T:
    """Call ``fn(*args)`` on every rank; if it raises on any rank, raise ``error`` on all of
    them.

    User callbacks (boundaries, velocities, values) may fail on the points of one rank
    only; raising there alone would leave the other ranks waiting in the next collective
    call.
    """
    problems: list[Problem] = []
    try:
        result = fn(*args)
    except MeshingError as e:
        result, problems = None, [Problem(_literal(str(e)), e.points, 1, e.refinable)]
    except Exception as e:  # any failure of a user callback, on any subset of the ranks
        text = _literal(f"{what} failed: {type(e).__name__}: {e}")
        result, problems = None, [Problem(text, np.zeros((0, 2)), 1, False)]
    raise_collective(comm, problems, error)
    return result  # type: ignore[return-value]


_VECTORS: dict[tuple[int, int], tuple[Any, Any, Any]] = {}
_MAX_VECTORS = 16


def _ghosted_vector(index_map, bs: int) -> tuple[Any, Any]:
    """A ghosted vector (and its PETSc view) on ``index_map``, reused between calls.

    Creating the PETSc vector and its scatter costs milliseconds, more than a reduction
    near Gamma; the last few are kept (with their index maps, so the keys stay valid).
    """
    key = (id(index_map), bs)
    entry = _VECTORS.get(key)
    if entry is None or entry[0] is not index_map:
        vec = la.vector(index_map, bs, dtype=np.float64)
        entry = (index_map, vec, vec.petsc_vec)
        if len(_VECTORS) >= _MAX_VECTORS:
            _VECTORS.pop(next(iter(_VECTORS)))
        _VECTORS[key] = entry
    return entry[1], entry[2]


def vertex_reduce(index_map, values: npt.ArrayLike, op: str = "sum") -> npt.NDArray[np.float64]:
    """Combine per-vertex contributions of all ranks, owned and ghost entries alike.

    Parameters
    ----------
    index_map
        Vertex index map of the mesh (``topology.index_map(0)``), or any index map whose
        local indices number the rows of ``values``.
    values
        Local contributions, ``(size_local + num_ghosts,)`` or, a block of values per
        vertex, ``(size_local + num_ghosts, bs)``.
    op
        ``"sum"``, ``"max"`` or ``"min"``.

    Returns
    -------
    The reduced values on owned and ghost vertices, shaped as ``values``.
    """
    sign = reduce_sign(op)
    values = np.asarray(values, dtype=np.float64)
    if values.ndim not in (1, 2) or len(values) != index_map.size_local + index_map.num_ghosts:
        raise ValueError(
            f"values must have one row per local vertex ({index_map.size_local} owned + "
            f"{index_map.num_ghosts} ghosts), got shape {values.shape}"
        )
    if index_map.comm.size == 1:
        return values.copy()
    bs = 1 if values.ndim == 1 else values.shape[1]
    if bs == 0:
        return values.copy()
    vec, pv = _ghosted_vector(index_map, bs)
    vec.array[:] = sign * values.ravel()
    combine_ghosts(pv, op)
    out = sign * vec.array.reshape(values.shape)
    return out


def reduce_sign(op: str) -> float:
    """The factor that turns a reduction ``op`` over the ranks into a sum or a maximum of
    stored values: -1 for "min" (``min(a, b) = -max(-a, -b)``), 1 for "sum" and "max".

    Raises
    ------
    ValueError
        For any other ``op``.
    """
    if op not in ("sum", "max", "min"):
        raise ValueError(f"op must be 'sum', 'max' or 'min', got {op!r}")
    return -1.0 if op == "min" else 1.0


def combine_ghosts(petsc_vec: Any, op: str) -> None:
    """Combine the owned and ghost entries of a ghosted PETSc vector over the ranks (values
    stored times :func:`reduce_sign`): the ghosts' values added to ("sum") or maxed into
    their owners', then the owners' results copied to every ghost (collective)."""
    from petsc4py import PETSc

    mode = PETSc.InsertMode.ADD_VALUES if op == "sum" else PETSc.InsertMode.MAX_VALUES
    petsc_vec.ghostUpdate(addv=mode, mode=PETSc.ScatterMode.REVERSE)
    petsc_vec.ghostUpdate(addv=PETSc.InsertMode.INSERT_VALUES, mode=PETSc.ScatterMode.FORWARD)
