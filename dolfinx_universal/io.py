"""Checkpoints of curved meshes of any degree (VTKHDF, facet-tag sidecar; adios4dolfinx
optional), and their redistribution over the ranks."""

# write_mesh / read_mesh store a triangle or tetrahedron mesh with a degree-k Lagrange
# coordinate element in DOLFINx's own VTKHDF format (dolfinx.io.vtkhdf; ParaView reads it).
# VTKHDF Lagrange cells have equispaced nodes, but DOLFINx 0.11 writes the nodes of the
# mesh's own variant and reads degree >= 3 back as equispaced: a GLL-warped degree-4 disc
# written as is comes back with an area error of 5e-5 instead of 1e-10. Hence write_mesh
# writes a copy whose nodes are the same map evaluated at equispaced points, and read_mesh
# evaluates the read map at GLL-warped points again. VTKHDF has no mesh tags in DOLFINx 0.11:
# facet tags go to a sidecar (tags_path), keyed by the file node indices of each facet's
# vertices (two for an edge, three for a face), matched on any number of ranks.
# write_fields writes functions for ParaView with VTXWriter (write-only). Function checkpoints
# that can be read back need adios4dolfinx, an optional path where an MPI-enabled adios2
# exists (PyPI's adios2 is serial and adios4dolfinx refuses it); this package does not use it.

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

from mpi4py import MPI

import basix
import basix.ufl
import numpy as np
import numpy.typing as npt
from dolfinx import fem, graph
from dolfinx import mesh as dmesh
from dolfinx.io import VTXWriter, distribute_entity_data, vtkhdf

from dolfinx_universal.backgrounds.lattice_tri import ghosted_partitioner

__all__ = ["read_mesh", "redistribute", "tags_path", "write_fields", "write_mesh"]

T = TypeVar("T")

_FORMAT_VERSION = 1


def tags_path(filename: str | Path) -> Path:
    """The facet-tag sidecar of a mesh file: ``disc.vtkhdf`` -> ``disc.tags.npz``.

    Parameters
    ----------
    filename
        The VTKHDF mesh file.

    Returns
    -------
    The sidecar's path (next to the mesh file).
    """
    return Path(filename).with_suffix(".tags.npz")


def _on_root(comm: MPI.Comm, action: Callable[[], T]) -> T:
    """Run ``action`` on rank 0 and broadcast its result; its error is raised on every rank."""
    result, error = None, None
    if comm.rank == 0:
        try:
            result = action()
        except Exception as exc:  # noqa: BLE001 - re-raised on every rank below
            error = f"{type(exc).__name__}: {exc}"
    result, error = comm.bcast((result, error), root=0)
    if error is not None:
        raise OSError(error)
    return result


_CELLS = (dmesh.CellType.triangle, dmesh.CellType.tetrahedron)


def _check_cells(msh: dmesh.Mesh, what: str) -> None:
    if msh.topology.cell_type not in _CELLS or len(msh.geometry.cmaps) != 1:
        raise ValueError(
            f"{what}: only triangle and tetrahedron meshes with one coordinate element are "
            f"supported, got {msh.topology.cell_type.name}"
        )


def _variant(msh: dmesh.Mesh) -> basix.LagrangeVariant:
    return basix.LagrangeVariant(msh.geometry.cmaps[0].variant)


def _facet_vertex_nodes(msh: dmesh.Mesh, facets: npt.NDArray[np.int32]) -> npt.NDArray[np.int32]:
    """Process-local geometry nodes of the ``tdim`` vertices of each facet, ``(n, tdim)``."""
    top = msh.topology
    tdim = top.dim
    top.create_connectivity(tdim - 1, 0)
    top.create_connectivity(0, tdim)
    f2v = top.connectivity(tdim - 1, 0).array.reshape(-1, tdim)[facets]
    nodes = dmesh.entities_to_geometry(msh, 0, f2v.ravel().astype(np.int32))
    return nodes.reshape(-1, tdim)


def _unique_rows(rows: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """Indices of the first occurrence of each distinct row of ``(m, k)``, in row order."""
    if len(rows) == 0:
        return np.zeros(0, dtype=np.int64)
    return np.unique(rows, axis=0, return_index=True)[1]


def write_mesh(
    filename: str | Path, mesh: dmesh.Mesh, facet_tags: dmesh.MeshTags | None = None
) -> None:
    """Write a triangle or tetrahedron mesh of any geometry degree (and its facet tags) to a
    VTKHDF file.

    The nodes written are the mesh's coordinate map evaluated at the equispaced Lagrange
    points of each cell (what VTKHDF and ParaView expect); ``mesh`` itself is not changed.
    Facet tags go to :func:`tags_path`; without tags, a stale sidecar is removed. Collective.

    Parameters
    ----------
    filename
        The VTKHDF file (conventionally ``.vtkhdf``), overwritten.
    mesh
        A triangle or tetrahedron mesh with a degree-k Lagrange coordinate element (any
        variant).
    facet_tags
        Tags of facets of ``mesh`` (owned and/or ghost facets), or ``None``.

    Raises
    ------
    ValueError
        If ``mesh`` is neither a triangle nor a tetrahedron mesh, or the tags are not facet
        tags.
    OSError
        If the sidecar cannot be written (on every rank).
    """
    _check_cells(mesh, "write_mesh")
    comm = mesh.comm
    tdim = mesh.topology.dim
    degree = mesh.geometry.cmaps[0].degree
    out = mesh
    if degree >= 3 and _variant(mesh) != basix.LagrangeVariant.equispaced:
        # Same topology, geometry = the same map interpolated at equispaced points.
        ce = fem.coordinate_element(
            mesh.topology.cell_type, degree, basix.LagrangeVariant.equispaced
        )
        out = fem.interpolate_geometry(mesh, ce)
    vtkhdf.write_mesh(str(filename), out)

    sidecar = tags_path(filename)
    if facet_tags is None:
        _on_root(comm, lambda: sidecar.unlink(missing_ok=True))
        comm.barrier()
        return
    if facet_tags.dim != tdim - 1:
        raise ValueError(
            f"write_mesh: facet_tags has dimension {facet_tags.dim}, expected {tdim - 1}"
        )
    imap = out.geometry.index_map()
    nodes = _facet_vertex_nodes(out, facet_tags.indices.astype(np.int32))
    # Written node order = global geometry index (each rank writes its owned range).
    rows = imap.local_to_global(nodes.ravel()).reshape(-1, tdim)
    rows = np.sort(rows.astype(np.int64), axis=1)
    gathered = comm.gather((rows, np.asarray(facet_tags.values)), root=0)

    def save() -> None:
        p = np.concatenate([g[0] for g in gathered]).reshape(-1, tdim)
        v = np.concatenate([g[1] for g in gathered])
        # A facet tagged on several ranks (ghosts) is stored once.
        first = _unique_rows(p)
        with open(sidecar, "wb") as f:  # np.savez would append ".npz" to other names
            np.savez(
                f,
                version=np.int64(_FORMAT_VERSION),
                dim=np.int64(facet_tags.dim),
                num_nodes=np.int64(imap.size_global),
                vertices=p[first],
                values=v[first],
            )

    _on_root(comm, save)
    comm.barrier()


def _facet_tags_of(
    msh: dmesh.Mesh, rows: npt.NDArray[np.int64], values: np.ndarray, dtype: npt.DTypeLike
) -> dmesh.MeshTags:
    """Facet tags of ``msh``, values of type ``dtype``, from facets given on any ranks as
    rows of facet-closure nodes (input indices of ``msh``) with ``values`` (int32, int64,
    float32 or float64: the types DOLFINx carries), sent to the ranks that hold them by
    :func:`dolfinx.io.distribute_entity_data` (owned and ghost facets; collective)."""
    tdim = msh.topology.dim
    entities, carried = distribute_entity_data(msh, tdim - 1, rows, values)
    msh.topology.create_connectivity(tdim - 1, tdim)
    return dmesh.meshtags_from_entities(
        msh, tdim - 1, graph.adjacencylist(entities), np.asarray(carried).astype(dtype)
    )


def _closure_rows(msh: dmesh.Mesh, vertex_nodes: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """Facets given by the global input indices of their ``tdim`` vertex nodes (any order),
    as the rows of facet-closure nodes that :func:`dolfinx.io.distribute_entity_data` takes:
    the vertex nodes at the positions of the vertices in the coordinate element's facet
    closure (the only columns it reads), the first of them repeated in the other columns."""
    tdim = msh.topology.dim
    layout = msh.geometry.cmaps[0].create_dof_layout()
    closure = list(layout.entity_closure_dofs(tdim - 1, 0))
    vertex_dofs = [layout.entity_dofs(0, i)[0] for i in range(tdim + 1)]
    at = [closure.index(d) for d in vertex_dofs if d in closure]
    rows = np.repeat(vertex_nodes[:, :1], len(closure), axis=1)
    rows[:, at] = vertex_nodes
    return rows


def _tags_from_file(raw: dmesh.Mesh, msh: dmesh.Mesh, sidecar: Path) -> dmesh.MeshTags | None:
    """Facet tags of ``msh`` (created from ``raw``) from the sidecar of the file of ``raw``.

    Rank 0 reads the sidecar and scatters its rows in equal parts. DOLFINx's
    :func:`~dolfinx.io.distribute_entity_data` then carries each facet, given by file node
    indices (the input indices of ``raw``), to the ranks of ``raw`` that hold its vertices,
    where they become global node numbers of ``raw``: the input indices of ``msh``, by which
    a second call carries them to the ranks of ``msh`` that hold the facet. No rank holds
    more than its share of the tags, except rank 0 while it reads them.
    """
    comm = msh.comm
    tdim = msh.topology.dim
    table: list[np.ndarray] = []  # rank 0: the rows and values, read with the header

    def load() -> tuple[int, int] | None:
        if not sidecar.exists():
            return None
        with np.load(sidecar) as d:
            header = int(d["num_nodes"]), int(d["dim"])
            rows = np.asarray(d["vertices"], dtype=np.int64)
            values = np.asarray(d["values"])
        if rows.ndim != 2 or rows.shape[1] != header[1] + 1 or len(values) != len(rows):
            raise ValueError(
                f"{sidecar} is malformed: vertices of shape {rows.shape} for facets of "
                f"dimension {header[1]} (expected ({len(values)}, {header[1] + 1}))"
            )
        table[:] = [rows, values]
        return header

    header = _on_root(comm, load)  # a sidecar that cannot be read fails on every rank
    if header is None:
        return None
    imap = raw.geometry.index_map()
    n = imap.size_global
    if header != (n, tdim - 1):
        raise ValueError(
            f"{sidecar} does not belong to its mesh file ({header[0]} nodes of facets of "
            f"dimension {header[1]} recorded, {n} nodes of a {tdim}D mesh read)"
        )
    parts = None
    if comm.rank == 0:
        rows, values = table
        cuts = np.linspace(0, len(rows), comm.size + 1).astype(np.int64)
        parts = [(rows[a:b], values[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]
    rows, values = comm.scatter(parts, root=0)
    dtype = values.dtype  # carried as int64 or float64 (int8 tags have no binding)
    carrier = np.int64 if np.issubdtype(dtype, np.integer) else np.float64
    # File node indices -> local vertices of `raw` -> global node numbers of `raw`.
    verts, values = distribute_entity_data(
        raw, tdim - 1, _closure_rows(raw, rows), values.astype(carrier)
    )
    verts = np.asarray(verts, dtype=np.int32).reshape(-1, tdim)
    raw.topology.create_connectivity(0, tdim)
    nodes = dmesh.entities_to_geometry(raw, 0, verts.ravel()).reshape(-1)
    glob = imap.local_to_global(nodes.astype(np.int32)).reshape(-1, tdim).astype(np.int64)
    # Global node numbers of `raw` (input indices of `msh`) -> facets of `msh`.
    return _facet_tags_of(msh, _closure_rows(msh, glob), values, dtype)


def read_mesh(
    comm: MPI.Comm,
    filename: str | Path,
    *,
    variant: basix.LagrangeVariant = basix.LagrangeVariant.gll_warped,
) -> tuple[dmesh.Mesh, dmesh.MeshTags | None]:
    """Read a triangle or tetrahedron mesh (and its facet tags) written by :func:`write_mesh`,
    on any ranks.

    The file's equispaced degree-k map is evaluated at the nodes of ``variant`` in every
    cell, and the mesh is recreated with that Lagrange coordinate element (geometric
    dimension 2 for triangles, 3 for tetrahedra) and shared-facet ghosts. Plain VTKHDF
    triangle and tetrahedron files of other writers are read too (without tags). Collective.

    Parameters
    ----------
    comm
        Communicator to distribute the mesh over (any size, not necessarily the writer's).
    filename
        The VTKHDF file.
    variant
        Lagrange variant of the returned coordinate element; the default ``gll_warped`` is
        that of :func:`~dolfinx_universal.curved.maps.curved_mesh` (irrelevant for degree <= 2).

    Returns
    -------
    mesh
        The mesh.
    facet_tags
        Its facet tags (owned and ghost facets) from :func:`tags_path`, or ``None`` when the
        file has no sidecar.

    Raises
    ------
    ValueError
        If the file is neither a triangle nor a tetrahedron mesh, or the sidecar belongs to
        another mesh.
    """
    raw = vtkhdf.read_mesh(comm, str(filename), gdim=3)
    _check_cells(raw, "read_mesh")
    tdim = raw.topology.dim
    gdim = tdim  # triangles in the plane, tetrahedra in space
    cell = raw.topology.cell_type.name
    degree = raw.geometry.cmaps[0].degree
    bcell = basix.CellType[cell]
    source = basix.create_element(basix.ElementFamily.P, bcell, degree, _variant(raw))
    target = basix.create_element(basix.ElementFamily.P, bcell, degree, variant)
    phi = source.tabulate(0, target.points)[0, :, :, 0]  # (target points, source nodes)
    dofmap = raw.geometry.dofmaps[0]
    imap = raw.geometry.index_map()
    # Rows of a geometry dofmap follow the reference node order of each cell (vertices,
    # edges in the cell's own direction, interior), as the coordinate element evaluates them.
    cell_x = np.einsum("pj,cjd->cpd", phi, raw.geometry.x[dofmap, :gdim])
    x = np.empty((imap.size_local + imap.num_ghosts, gdim))
    x[dofmap.ravel()] = cell_x.reshape(-1, gdim)  # shared nodes agree to rounding
    msh = _recreate(raw, x, variant)
    return msh, _tags_from_file(raw, msh, tags_path(filename))


def _recreate(msh: dmesh.Mesh, x: npt.NDArray[np.float64], variant: basix.LagrangeVariant):
    """A mesh with the cells of ``msh`` and node coordinates ``x`` (one row per local
    geometry node of ``msh``, ``gdim`` columns), coordinate element of ``msh``'s degree
    and ``variant``, partitioned by DOLFINx's graph partitioner with shared-facet ghosts
    (collective). The global node numbers of ``msh`` are the new mesh's input indices."""
    tdim, gdim = msh.topology.dim, x.shape[1]
    imap = msh.geometry.index_map()
    dofmap = msh.geometry.dofmaps[0]
    num_cells = msh.topology.index_map(tdim).size_local
    # Rows of a geometry dofmap follow the coordinate element's node order: the same global
    # node numbers give the same cells (the width, not -1: a rank may hold no cells).
    cells = imap.local_to_global(dofmap[:num_cells].ravel()).reshape(num_cells, dofmap.shape[1])
    cell = msh.topology.cell_type.name
    degree = msh.geometry.cmaps[0].degree
    element = basix.ufl.element("Lagrange", cell, degree, shape=(gdim,), lagrange_variant=variant)
    comm = msh.comm
    return dmesh.create_mesh(
        comm,
        cells.astype(np.int64),
        element,
        np.ascontiguousarray(x[: imap.size_local]),
        partitioner=ghosted_partitioner() if comm.size > 1 else None,
    )


def redistribute(
    mesh: dmesh.Mesh, facet_tags: dmesh.MeshTags | None = None
) -> tuple[dmesh.Mesh, dmesh.MeshTags | None]:
    """The same mesh and facet tags, distributed by DOLFINx's graph partitioner (collective).

    The meshes of this package keep the partition of their background: each rank holds the cells
    of its part of the background near Gamma, so the ranks whose parts Gamma crosses hold most
    of the cells (3-4 times the mean on 16 ranks for a torus, measured with
    ``benchmarks/scaling.py``). A solve on the mesh is shared as unevenly. This recreates the
    mesh with the same cells and geometry nodes (any degree, the same coordinate element) and
    shared-facet ghosts, partitioned by DOLFINx's graph partitioner (SCOTCH in the wheel), and
    carries the facet tags over. Meant for static meshes
    (:func:`~dolfinx_universal.meshing.domain.mesh_domain`): the result is a new mesh, unrelated
    to the background, so a :class:`~dolfinx_universal.moving.domain.MovingDomain` keeps its
    own.

    Parameters
    ----------
    mesh
        A triangle or tetrahedron mesh with one Lagrange coordinate element.
    facet_tags
        Its facet tags, integer values (optional).

    Returns
    -------
    mesh
        The redistributed mesh (on one rank: a copy), with the name of ``mesh``.
    facet_tags
        Its facet tags, the same facets, values (int32) and name, or ``None`` without
        ``facet_tags``.

    Raises
    ------
    ValueError
        If the mesh has another cell type or more than one coordinate element, or the tags
        are not of its facets or not integers.
    """
    _check_cells(mesh, "redistribute")
    if facet_tags is not None and (
        facet_tags.dim != mesh.topology.dim - 1
        or not np.issubdtype(facet_tags.values.dtype, np.integer)
    ):
        raise ValueError(
            f"redistribute: facet_tags must tag facets (dimension {mesh.topology.dim - 1}) "
            f"with integers, got dimension {facet_tags.dim} and {facet_tags.values.dtype}"
        )
    tdim = mesh.topology.dim
    new = _recreate(mesh, mesh.geometry.x[:, : mesh.geometry.dim], _variant(mesh))
    new.name = mesh.name
    if facet_tags is None:
        return new, None
    # Each owned tagged facet by the global nodes of its closure in one of its cells (the
    # vertices first, as DOLFINx's reader of gmsh files passes them).
    top = mesh.topology
    top.create_connectivity(tdim - 1, tdim)
    top.create_connectivity(tdim, tdim - 1)
    owned = facet_tags.indices < top.index_map(tdim - 1).size_local
    facets, values = facet_tags.indices[owned], facet_tags.values[owned]
    f2c, c2f = top.connectivity(tdim - 1, tdim), top.connectivity(tdim, tdim - 1)
    cell_of = f2c.array[f2c.offsets[facets]]
    local = np.argmax(c2f.array.reshape(-1, tdim + 1)[cell_of] == facets[:, None], axis=1)
    layout = mesh.geometry.cmaps[0].create_dof_layout()
    closure = np.array([layout.entity_closure_dofs(tdim - 1, i) for i in range(tdim + 1)])
    nodes = mesh.geometry.dofmaps[0][cell_of[:, None], closure[local]]
    imap = mesh.geometry.index_map()
    glob = imap.local_to_global(nodes.ravel().astype(np.int32)).reshape(nodes.shape)
    tags = _facet_tags_of(new, glob.astype(np.int64), values.astype(np.int32), np.int32)
    tags.name = facet_tags.name
    return new, tags


def write_fields(
    filename: str | Path,
    functions: fem.Function | Sequence[fem.Function],
    time: float = 0.0,
    engine: str = "BPFile",
) -> None:
    """Write functions of any Lagrange degree for ParaView with ``dolfinx.io.VTXWriter``.

    VTX writes the functions' degrees of freedom as the nodes of VTK Lagrange cells, which
    ParaView takes as equispaced; functions of degree >= 3 in another variant (basix's
    default is GLL-warped) are therefore first interpolated, exactly, into the equispaced
    space of the same degree, so that ParaView shows the true fields on the true curved
    cells (to the functions' degree). The output (an ADIOS2 ``.bp`` folder) is write-only:
    use :func:`write_mesh` for checkpoints of the mesh. Collective.

    Parameters
    ----------
    filename
        Output folder, conventionally ``name.bp``; overwritten.
    functions
        One function or several on the same mesh with the same element (a VTX requirement).
    time
        Time stamp of this single step.
    engine
        ADIOS2 engine.
    """
    funcs = [functions] if isinstance(functions, fem.Function) else list(functions)
    if not funcs:
        raise ValueError("write_fields: no functions given")
    out = []
    for u in funcs:
        e = u.function_space.ufl_element()
        variant = getattr(e, "lagrange_variant", basix.LagrangeVariant.unset)
        if e.degree >= 3 and variant not in (
            basix.LagrangeVariant.equispaced,
            basix.LagrangeVariant.unset,
        ):
            msh = u.function_space.mesh
            shape = e.reference_value_shape
            eq = basix.ufl.element(
                e.family_name,
                msh.basix_cell(),
                e.degree,
                lagrange_variant=basix.LagrangeVariant.equispaced,
                shape=shape if shape else None,
                discontinuous=e.discontinuous,
            )
            w = fem.Function(fem.functionspace(msh, eq), name=u.name)
            w.interpolate(u)
            u = w
        out.append(u)
    with VTXWriter(out[0].function_space.mesh.comm, str(filename), out, engine=engine) as f:
        f.write(time)
