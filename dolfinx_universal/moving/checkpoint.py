"""The HDF5 details of the checkpoints of
:class:`~dolfinx_universal.moving.stepping.TimeStepper`: dof values in an order that does
not depend on the number of ranks, the solution at the geometry nodes for ParaView,
PETSc's HDF5 viewer for the rest.

A checkpoint is one VTKHDF file (HDF5). DOLFINx writes its ``/VTKHDF`` group (the current
mesh, with the solution as point data), then PETSc's HDF5 viewer appends the group
``/TimeStepper`` with the state: small datasets ``format``, ``scheme`` (character codes),
``dt``, ``times``, ``has_slope``, ``sizes`` (the number of dof values, of node coordinates,
and the number of ranks that wrote the file), ``background`` (the background's nodes, by
which a reader checks that it numbers the cells alike) and, per level ``i``, ``values_i``
and, for levels with a Runge–Kutta slope, ``slope_i`` and ``velocity_i`` (the nodes'
velocity). Node arrays go through the vector Lagrange space of the geometry. Dof values
are written in the order of a key that is the same on any number of ranks
(:func:`dof_keys`), so that a checkpoint written on some number of ranks is read on any
other. Finding that order (:class:`DofOrder`, once per stepper and space) takes a PETSc
vector of the number of cells times the dofs per cell.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from mpi4py import MPI
from petsc4py import PETSc

import basix.ufl
import numpy as np
import numpy.typing as npt
from dolfinx import fem

from dolfinx_universal.core.collective import vertex_reduce

__all__ = ["DofOrder", "dof_keys", "point_values"]

FORMAT_VERSION = 1
"""The layout of the group ``/TimeStepper``; a reader refuses other versions."""

GROUP = "/TimeStepper"
"""The HDF5 group of the state, next to DOLFINx's ``/VTKHDF``."""


def _flat_dofmap(V: fem.FunctionSpace) -> npt.NDArray[np.int64]:
    """The cells' dofs as indices of ``Function.x.array`` (blocks unrolled)."""
    dofs = np.asarray(V.dofmap.list, dtype=np.int64)
    bs = V.dofmap.index_map_bs
    if bs == 1:
        return dofs
    return (dofs[:, :, None] * bs + np.arange(bs)).reshape(len(dofs), -1)


def dof_keys(V: fem.FunctionSpace) -> npt.NDArray[np.int64]:
    """A key of every dof of ``V`` that does not depend on the number of ranks (collective).

    The key of the dof in slot ``j`` of cell ``c``'s dof list is
    ``original_cell_index[c] * n + j`` (``n`` dofs per cell); a dof takes the smallest key
    over the cells holding it, on all ranks. The keys of a space are distinct. Slot ``j``
    is the same point of the cell on any number of ranks: the cells keep their vertices'
    input order, and DOLFINx orders each cell's dof list as the reference element's (the
    dofs of a shared edge or face, numbered along the entity's global orientation, are
    permuted into each cell's reference order), so no permutation depends on the
    partition (``tests/test_checkpoint.py`` checks it for the two dofs of each P3 edge,
    blocked and mixed spaces).

    Parameters
    ----------
    V
        A Lagrange space (scalar, blocked or mixed) on a mesh whose
        ``topology.original_cell_index`` numbers the cells of the input mesh.

    Returns
    -------
    The keys of the entries of ``Function.x.array`` (owned and ghost).
    """
    mesh = V.mesh
    tdim = mesh.topology.dim
    cells = mesh.topology.index_map(tdim)
    num_cells = cells.size_local + cells.num_ghosts
    original = np.asarray(mesh.topology.original_cell_index, dtype=np.int64)
    if len(original) < num_cells:
        raise RuntimeError(
            "the mesh does not number its cells in the input mesh (topology."
            "original_cell_index): a checkpoint needs it"
        )
    dofs = _flat_dofmap(V)[:num_cells]
    n = dofs.shape[1]
    key = original[:num_cells, None] * n + np.arange(n)
    imap, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    smallest = np.full((imap.size_local + imap.num_ghosts) * bs, np.inf)
    np.minimum.at(smallest, dofs.ravel(), key.ravel().astype(np.float64))  # exact below 2^53
    reduced = vertex_reduce(imap, smallest.reshape(-1, bs), "min").ravel()
    return reduced.astype(np.int64)


class DofOrder:
    """The owned dofs of a space and their places in a file ordered by :func:`dof_keys`
    (collective): the dataset of a function is its values sorted by key, the same for any
    number of ranks.

    Parameters
    ----------
    V
        The space (see :func:`dof_keys`).
    """

    def __init__(self, V: fem.FunctionSpace) -> None:
        comm = V.mesh.comm
        imap, bs = V.dofmap.index_map, V.dofmap.index_map_bs
        self.V = V
        self.owned = imap.size_local * bs
        self.size = imap.size_global * bs
        """The number of values in the file: the space's global dimension."""
        keys = dof_keys(V)[: self.owned]
        span = comm.allreduce(int(keys.max(initial=-1)), op=MPI.MAX) + 1
        if span > np.iinfo(PETSc.IntType).max:  # the same on every rank
            raise RuntimeError(
                f"{span} dof keys (cells times dofs per cell) exceed PETSc's "
                f"{np.dtype(PETSc.IntType).name} indices: checkpoints need 64-bit PETSc here"
            )
        # the place of each key among all keys: mark them in a vector indexed by key,
        # then count the marks before each (a local running sum and a scan over the ranks)
        self._local = PETSc.Vec().createMPI((self.owned, PETSc.DETERMINE), comm=comm)
        start = self._local.getOwnershipRange()[0]
        mine = PETSc.IS().createStride(self.owned, first=start, step=1, comm=comm)
        marks = PETSc.Vec().createMPI((PETSc.DECIDE, span), comm=comm)
        to_keys = PETSc.Scatter().create(
            self._local,
            mine,
            marks,
            PETSc.IS().createGeneral(keys.astype(PETSc.IntType), comm=comm),  # type: ignore[arg-type]
        )
        self._local.set(1.0)
        marks.set(0.0)
        to_keys.scatter(self._local, marks, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
        count = np.cumsum(marks.getArray(readonly=True))
        before = comm.exscan(float(count[-1]) if len(count) else 0.0)
        marks.getArray()[:] = (before or 0.0) + count - 1.0
        if comm.allreduce(float(count[-1]) if len(count) else 0.0) != self.size:
            raise RuntimeError("dof keys are not distinct")  # every rank: a global count
        to_keys.scatter(marks, self._local, PETSc.InsertMode.INSERT, PETSc.ScatterMode.REVERSE)
        places = np.rint(self._local.getArray(readonly=True)).astype(PETSc.IntType)
        self._file = PETSc.Vec().createMPI((PETSc.DECIDE, self.size), comm=comm)
        self._scatter = PETSc.Scatter().create(
            self._local, mine, self._file, PETSc.IS().createGeneral(places, comm=comm)
        )
        for obj in (mine, marks, to_keys):
            obj.destroy()

    def write(self, viewer: PETSc.Viewer, name: str, values: npt.NDArray[np.float64]) -> None:
        """Write the owned entries of ``values`` (a ``Function.x.array``) as the dataset
        ``name`` of the viewer's current group (collective)."""
        self._local.getArray()[:] = values[: self.owned]
        self._scatter.scatter(
            self._local, self._file, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD
        )
        self._file.setName(name)
        self._file.view(viewer)

    def read(self, viewer: PETSc.Viewer, name: str) -> npt.NDArray[np.float64]:
        """The dataset ``name`` of the viewer's current group as a ``Function.x.array``,
        ghosts included (collective). The dataset must hold :attr:`size` values."""
        self._file.setName(name)
        self._file.load(viewer)
        self._scatter.scatter(
            self._file, self._local, PETSc.InsertMode.INSERT, PETSc.ScatterMode.REVERSE
        )
        u = fem.Function(self.V)
        u.x.array[: self.owned] = self._local.getArray(readonly=True)
        u.x.scatter_forward()
        return u.x.array.copy()

    def destroy(self) -> None:
        """Free the PETSc objects (collective)."""
        for obj in (self._local, self._file, self._scatter):
            obj.destroy()


def point_values(
    u: fem.Function, degree: int, active: npt.NDArray[np.bool_]
) -> npt.NDArray[np.float64]:
    """The values of ``u`` at the owned geometry nodes of its mesh, for
    :func:`dolfinx.io.vtkhdf.write_point_data` (collective).

    ``u`` is interpolated into the Lagrange space of the geometry (degree ``degree``, GLL
    points); a mixed function gives its sub-functions' components side by side (a
    Taylor–Hood pair in 2D: ``u_x, u_y, p``). A vector of two components gets a zero third
    one (VTK's vectors have three). Nodes of no active cell (outside the domain, where the
    values mean nothing) get NaN.

    Returns
    -------
    ``(owned nodes, components)``.
    """
    V = u.function_space
    mesh = V.mesh
    gdofmap = mesh.geometry.dofmaps[0]
    nodes = mesh.geometry.index_map()
    mixed = V.ufl_element().is_mixed
    parts = [u.sub(i).collapse() for i in range(V.num_sub_spaces)] if mixed else [u]
    columns = []
    for part in parts:
        shape = tuple(part.function_space.ufl_element().reference_value_shape)
        size = int(np.prod(shape)) if shape else 1
        Q = fem.functionspace(
            mesh,
            basix.ufl.element(
                "Lagrange",
                mesh.basix_cell(),
                degree,
                basix.LagrangeVariant.gll_warped,
                shape=shape or None,
            ),
        )
        q = fem.Function(Q)
        q.interpolate(part)
        node_of_dof = np.empty(len(mesh.geometry.x), dtype=np.int64)
        node_of_dof[Q.dofmap.list] = gdofmap  # the geometry's element: a node each
        at_nodes = np.empty((len(node_of_dof), size))
        at_nodes[node_of_dof] = q.x.array.reshape(-1, size)
        columns.append(at_nodes)
        if size == 2 and not mixed:
            columns.append(np.zeros((len(node_of_dof), 1)))
    values = np.hstack(columns)
    inside = np.zeros(len(values))
    inside[gdofmap[np.flatnonzero(active)]] = 1.0
    inside = vertex_reduce(nodes, inside, "max")
    values[inside == 0.0] = np.nan
    return values[: nodes.size_local]


def file_kind(path: str | Path) -> str:
    """``"missing"``, ``"hdf5"`` (the HDF5 signature at the start) or ``"other"``."""
    try:
        with open(path, "rb") as f:
            return "hdf5" if f.read(8) == b"\x89HDF\r\n\x1a\n" else "other"
    except FileNotFoundError:
        return "missing"
    except OSError:  # a folder, no permission
        return "other"


def open_viewer(path: str | Path, mode: str, comm: MPI.Comm) -> PETSc.ViewerHDF5:
    """PETSc's HDF5 viewer of ``path`` (``"a"``: append, ``"r"``: read) in the group
    :data:`GROUP` (collective)."""
    viewer = PETSc.ViewerHDF5().create(
        str(path),
        mode=mode,
        comm=comm,  # type: ignore[arg-type]  # petsc4py accepts an mpi4py Comm
    )
    viewer.pushGroup(GROUP)
    return viewer


def write_small(viewer: PETSc.Viewer, name: str, values: Sequence[float]) -> None:
    """A short dataset of numbers, written by rank 0 (collective)."""
    comm = viewer.getComm()
    data = np.asarray(values, dtype=np.float64)
    first = comm.getRank() == 0
    vec = PETSc.Vec().createMPI((len(data) if first else 0, len(data)), comm=comm)
    vec.getArray()[:] = data if first else data[:0]
    vec.setName(name)
    vec.view(viewer)
    vec.destroy()


def read_small(viewer: PETSc.Viewer, name: str) -> npt.NDArray[np.float64]:
    """A short dataset of numbers, on every rank (collective)."""
    comm = viewer.getComm()
    vec = PETSc.Vec().create(comm=comm)
    vec.setName(name)
    try:
        vec.load(viewer)
        scatter, whole = PETSc.Scatter.toAll(vec)
        scatter.scatter(vec, whole, PETSc.InsertMode.INSERT, PETSc.ScatterMode.FORWARD)
        out = whole.getArray(readonly=True).copy()
        scatter.destroy()
        whole.destroy()
    finally:
        vec.destroy()
    return out
