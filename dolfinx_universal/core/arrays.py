"""The array types, and the small input checks, array and planar vector helpers every stage
shares."""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import Any

import numpy as np
import numpy.typing as npt

from dolfinx_universal.core.compiled import pointer, relax_kernels

__all__ = [
    "Bool",
    "Float",
    "Int",
    "all_rows",
    "any_rows",
    "as_points",
    "cross2",
    "distinct_rows",
    "kd_query",
    "lagrange_element",
    "mirror_line",
    "norm2",
    "positive",
    "project_together",
    "write_cell_nodes",
]

Float = npt.NDArray[np.float64]
"""Real arrays (coordinates, distances, signs)."""
Int = npt.NDArray[np.signedinteger[Any]]
"""Index arrays (vertices, cells; int32 from DOLFINx, int64 or intp from numpy)."""
Bool = npt.NDArray[np.bool_]
"""Flag arrays."""


def as_points(x: npt.ArrayLike, name: str = "x", dim: int = 2) -> Float:
    """``x`` as a contiguous float64 array ``(n, dim)``, checked finite.

    ``dim = 2`` (planar boundaries): ``(n, 2)`` or ``(n, 3)``, of which the first two columns
    are kept. ``dim = 3`` (surfaces): exactly ``(n, 3)``.
    """
    a = np.asarray(x, dtype=np.float64)
    if dim == 3:
        if a.ndim != 2 or a.shape[1] != 3:
            raise ValueError(f"{name} must have shape (n, 3), got {a.shape}")
        a = np.ascontiguousarray(a)
    elif a.ndim != 2 or a.shape[1] not in (2, 3):
        raise ValueError(f"{name} must have shape (n, 2) or (n, 3), got {a.shape}")
    else:
        a = np.ascontiguousarray(a[:, :2])
    if not np.isfinite(a).all():  # (one reduction over the array; rows only to report)
        i = int(np.argmax(~np.isfinite(a).all(axis=1)))
        kind = "NaN" if np.isnan(a[i]).any() else "inf"
        raise ValueError(f"{name} contains {kind} at index {i} ({name}={a[i].tolist()})")
    return a


def as_box(box: npt.ArrayLike, dim: int | None = None) -> Float:
    """Corners ``[[min], [max]]`` of a box: ``dim`` finite coordinates each (2 or 3 when
    ``dim`` is None), min < max; a ``ValueError`` that says so otherwise."""
    try:
        b = np.asarray(box, dtype=np.float64)
    except (TypeError, ValueError):
        b = np.zeros((0,))
    dims = (2, 3) if dim is None else (dim,)
    if b.ndim != 2 or b.shape[0] != 2 or b.shape[1] not in dims or not np.isfinite(b).all():
        form = {2: "[[x0, y0], [x1, y1]]", 3: "[[x0, y0, z0], [x1, y1, z1]]"}
        want = form[2] + " (or 3D)" if dim is None else form[dim]
        raise ValueError(f"box must be {want} with finite coordinates, got {box!r}")
    if not (b[1] > b[0]).all():
        raise ValueError(f"box must be given with its lower corner first, got {b.tolist()}")
    return b


def positive(value: float, name: str) -> float:
    """``value`` as a float, checked positive and finite (``name`` for the error)."""
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value}")
    return value


def any_rows(a: Bool) -> Bool:
    """``a.any(axis=1)`` of a boolean ``(m, k)`` array, by columns (a reduction along a
    short axis is slow in numpy)."""
    out = a[:, 0].copy()
    for k in range(1, a.shape[1]):
        out |= a[:, k]
    return out


def all_rows(a: Bool) -> Bool:
    """``a.all(axis=1)`` of a boolean ``(m, k)`` array, by columns (see :func:`any_rows`)."""
    out = a[:, 0].copy()
    for k in range(1, a.shape[1]):
        out &= a[:, k]
    return out


def norm2(v: Float) -> Float:
    """Euclidean norms of planar vectors ``(..., 2)``."""
    return np.sqrt(v[..., 0] ** 2 + v[..., 1] ** 2)


def cross2(u: Float, v: Float) -> Float:
    """The planar cross product ``u_x v_y - u_y v_x`` of vectors ``(..., 2)``."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


@lru_cache(maxsize=32)
def lagrange_element(cell: str, degree: int, variant: Any = None) -> Any:
    """The basix Lagrange element of ``cell`` (``"triangle"``, ``"tetrahedron"``) of degree
    ``degree``: GLL-warped (the variant of DOLFINx's curved coordinate maps) unless another
    ``basix.LagrangeVariant`` is given. Built once per argument set."""
    import basix

    if variant is None:
        variant = basix.LagrangeVariant.gll_warped
    return basix.create_element(basix.ElementFamily.P, basix.CellType[cell], int(degree), variant)


def readonly(a: npt.NDArray) -> npt.NDArray:
    """``a`` as a contiguous read-only array (tables and samples that callers share)."""
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


THREADED_QUERY = 10_000
"""Points from which :func:`kd_query` runs a k-d tree query on all cores. Measured on an
idle 2-core machine: threads cost about 0.2 ms per query to start and join, twice the time
of a 1e3-point query; from 1e4 points (0.2-0.4 us each on one thread) they gain 1-1.9x,
from 1e5 points 1.7-2.0x."""


def kd_query(tree: Any, x: Float, **kwargs: Any) -> tuple[Any, Any]:
    """``tree.query(x, **kwargs)`` (a ``scipy.spatial.cKDTree``) on one thread, or on all
    cores (scipy's ``workers=-1``) for a query of at least :data:`THREADED_QUERY` points in a
    run of one MPI process.

    scipy starts Python threads for every threaded query, which a small query does not repay
    (0.2 ms per query on an idle machine, more when other work holds the cores: with threads
    for every query, planar ``mesh_domain`` on 24 random domains took 1.4x as long on an idle
    2-core machine, 2.5x with another job on the second core), and under MPI the ranks
    already occupy the cores, so threads only compete with them. Each point's answer is
    computed alone, so the results do not depend on the choice.
    """
    from mpi4py import MPI

    threaded = len(x) >= THREADED_QUERY and MPI.COMM_WORLD.size == 1
    return tree.query(x, workers=-1 if threaded else 1, **kwargs)


def rot90(v: Float) -> Float:
    """Vectors ``(n, 2)`` rotated by +90 degrees (the tangent of an outward normal)."""
    return np.column_stack([-v[:, 1], v[:, 0]])


def mirror_line(mirror: tuple[npt.ArrayLike, npt.ArrayLike], gdim: int) -> tuple[Float, Float]:
    """The point and the unit normal of a mirror line (plane) ``(point, normal)`` of ``gdim``
    finite numbers each; ``ValueError`` for anything else or a zero normal."""
    point = np.asarray(mirror[0], dtype=np.float64).reshape(-1)
    normal = np.asarray(mirror[1], dtype=np.float64).reshape(-1)
    length = float(np.sqrt(normal @ normal)) if len(normal) == gdim else 0.0
    if len(point) != gdim or not np.all(np.isfinite(point)) or not 0.0 < length < np.inf:
        raise ValueError(
            f"mirror must be (point, normal) of {gdim} finite numbers each, the normal "
            f"nonzero: {mirror}"
        )
    return point, normal / length


def distinct_rows(x: Float) -> tuple[Int, Int | None]:
    """The first of each set of bitwise equal rows of ``x (n, dim)`` and, for every row,
    the position of its set's among them; ``inverse = None`` where the rows are all
    distinct or the C kernels are not built (then every row is its own)."""
    kernels = relax_kernels()
    n = len(x)
    if kernels is None or n < 2 or n >= 2**31 or x.shape[1] > 4:
        return np.arange(n), None
    x = np.ascontiguousarray(x, dtype=np.float64)
    size = 1 << int(2 * n - 1).bit_length()
    table = np.full(size, -1, dtype=np.int32)
    first, inverse = np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64)
    ffi = kernels.ffi
    count = kernels.lib.distinct_rows(
        pointer(ffi, x, "double"), n, x.shape[1], pointer(ffi, table, "int32_t"), size,
        pointer(ffi, first, "int64_t"), pointer(ffi, inverse, "int64_t"),
    )  # fmt: skip
    if count == n:
        return first, None
    return first[:count], inverse


def write_cell_nodes(
    x: Float, dofmap: Int, cells: Int, nodes: Float, which: Int | None = None
) -> None:
    """``x[dofmap[cells], :gdim] = nodes[which]`` (``nodes (k, ndofs, gdim)``, ``which``
    default all of them in order), cell after cell (a node shared by two cells gets the
    later one's value): a C loop where the kernels are built."""
    m, gdim = len(cells), nodes.shape[-1]
    which = np.arange(m) if which is None else which
    kernels = relax_kernels()
    if kernels is None or not (x.flags.c_contiguous and x.shape[1] == 3):
        x[dofmap[cells].ravel(), :gdim] = nodes[which].reshape(-1, gdim)
        return
    ffi = kernels.ffi
    cells, which = (np.ascontiguousarray(a, dtype=np.int64) for a in (cells, which))
    dofmap = np.ascontiguousarray(dofmap, dtype=np.int32)
    nodes = np.ascontiguousarray(nodes, dtype=np.float64)
    kernels.lib.write_cell_nodes(
        pointer(ffi, cells, "int64_t"), pointer(ffi, which, "int64_t"), m,
        pointer(ffi, dofmap, "int32_t"), dofmap.shape[1], pointer(ffi, nodes, "double"), gdim,
        pointer(ffi, x, "double"),
    )  # fmt: skip


def project_together(
    closest_point: Callable[[Float], Float], queries: list[Float], dim: int
) -> list[Float]:
    """Closest points of the points of every array of ``queries`` (shapes ``(..., dim)``),
    by one call of ``closest_point`` (none when there is no point); each result has the
    shape of its query. A point's projection does not depend on the other points of the
    call, so grouping the queries of several cells changes no value, and neither does
    projecting each distinct point once (bitwise equal rows: a node or a blend point on an
    entity shared by several cells is queried by each; on the curved tetrahedra of a torus
    154e3 queries hold 67e3 distinct points)."""
    if not queries:
        return []
    flat = np.concatenate([q.reshape(-1, dim) for q in queries])
    first, inverse = distinct_rows(flat)
    if not len(flat):
        proj = flat
    elif inverse is None:
        proj = np.asarray(closest_point(flat), dtype=np.float64)
    else:
        proj = np.asarray(closest_point(flat[first]), dtype=np.float64)[inverse]
    ends = np.cumsum([q.size // dim for q in queries])[:-1]
    return [p.reshape(q.shape) for p, q in zip(np.split(proj, ends), queries, strict=True)]
