"""Checks of conforming meshes that do not use the package's own checks.

:func:`check_mesh` measures a DOLFINx mesh of a domain with UFL, DOLFINx and SciPy only, the
boundary object serving as the definition of Gamma:

* ``det J`` (``ufl.JacobianDeterminant``, through :class:`dolfinx.fem.Expression`) on the
  points of a lattice of the reference triangle, on every cell. Affine cells are recognised
  from the coordinate map on a lattice of ``2q`` subdivisions (unisolvent for degree ``q``,
  so agreeing with the affine map there means being affine); they are checked there (their
  ``det J`` is constant, and its sign is the orientation), the others on the fine lattice.
* Geometry nodes of the facets tagged :data:`~dolfinx_universal.IMMERSED` lie on Gamma: the
  package puts them there by closest-point projection, so ``|phi|`` must be rounding only.
* Area against the exact area. Omega_h and Omega differ by the region between Gamma_h and
  Gamma; its area is ``S = int_{Gamma_h} |phi| ds`` to relative order ``max(|phi| kappa,
  theta^2)`` (``theta``: angle between Gamma_h and Gamma), and ``area_h - area = int_{Gamma_h}
  phi ds`` to the same order. For a degree-q boundary ``|phi| = O(h^(q+1))`` (``O(h^2)`` for
  straight facets), so ``S = O(L h_near^(q+1))``: the tolerance of the brief's
  ``C L h_near^(q+1)`` with the constant measured on the mesh (Gauss quadrature on every
  immersed facet) instead of guessed. A mesh with missing or overlapping parts, or a wrong
  exact area, fails it however fine the mesh.
* Gamma_h is a set of closed simple curves (every vertex on two immersed facets) and has the
  expected number of loops; the mesh (cells connected through facets) has the expected
  number of pieces; every exterior facet is tagged, and immersed tags only exterior facets.

Collective; every rank returns the same dictionary.
"""

from __future__ import annotations

from typing import Any

from mpi4py import MPI

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh
from scipy.sparse.csgraph import connected_components

import dolfinx_universal as du
from dolfinx_universal.curved import maps_tri

__all__ = ["check_domain_mesh", "check_mesh", "curved_triangle_nodes", "reference_lattice"]

Float = npt.NDArray[np.float64]
Int = npt.NDArray[np.int64]

NODE_TOL = 1e-10
"""Largest ``|phi|`` of a node on Gamma, relative to the extent of Gamma."""
AREA_FACTOR = 0.25
"""Allowed mismatch ``|area_h - area - int phi ds|`` relative to ``int |phi| ds``."""
BULGE = 0.25
"""Largest distance from an immersed facet to Gamma, relative to the facet's chord."""
CHUNK = 4096
"""Cells per :meth:`dolfinx.fem.Expression.eval` call (bounds the memory)."""

# Reference edges of the triangle (edge i opposite vertex i): origin and direction.
_EDGE_ORIGIN = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
_EDGE_DIR = np.array([[-1.0, 1.0], [0.0, 1.0], [1.0, 0.0]])


def reference_lattice(n: int) -> Float:
    """Points ``(i/n, j/n)``, ``i + j <= n``, of the reference triangle; the three vertices first.

    Parameters
    ----------
    n
        Subdivisions per edge.

    Returns
    -------
    ``((n + 1)(n + 2) / 2, 2)`` points.
    """
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    pts = np.column_stack([i[keep], j[keep]]).astype(np.float64) / n
    first = [int(np.flatnonzero((pts == v).all(axis=1))[0]) for v in ([0, 0], [1, 0], [0, 1])]
    rest = np.setdiff1d(np.arange(len(pts)), first)
    return pts[np.concatenate([first, rest])]


def curved_triangle_nodes(cm: Any, degree: int, kind: str) -> Float:
    """Images of the degree-``degree`` reference nodes of every local triangle of the
    conforming mesh ``cm`` under the map ``kind``, ``(cells, ndofs, 2)``
    (:func:`~dolfinx_universal.curved.maps_tri.map_nodes` on all of them)."""
    return maps_tri.map_nodes(
        cm.cells, cm.x, cm.background_x, cm.sign, degree, kind, cm.boundary.closest_point
    )


def _eval(expr: fem.Expression, msh: dmesh.Mesh, cells: npt.NDArray, shape: tuple) -> Float:
    """``expr`` on ``cells``, shape ``(len(cells), *shape)``, in chunks."""
    out = np.empty((len(cells), *shape))
    for s in range(0, len(cells), CHUNK):
        c = np.ascontiguousarray(cells[s : s + CHUNK], dtype=np.int32)
        out[s : s + len(c)] = np.asarray(expr.eval(msh, c)).reshape(len(c), *shape)
    return out


def _gather_min(comm: MPI.Comm, value: float, where: Any) -> tuple[float, Any]:
    """Global minimum of ``value`` and the ``where`` of the rank that holds it."""
    return min(comm.allgather((value, where)), key=lambda vw: vw[0])


def _fmt(p: Any) -> str:
    return "(" + ", ".join(f"{v:.6g}" for v in np.asarray(p, dtype=float).ravel()[:2]) + ")"


def _jacobians(msh: dmesh.Mesh, lattice: int, full: bool) -> dict[str, Any]:
    """Local ``det J`` statistics of the owned cells (see the module docstring)."""
    q = msh.geometry.cmaps[0].degree
    ncells = msh.topology.index_map(2).size_local
    cells = np.arange(ncells, dtype=np.int32)
    detj = ufl.JacobianDeterminant(msh)
    x = ufl.SpatialCoordinate(msh)
    coarse = reference_lattice(q)
    e = fem.Expression(ufl.as_vector([detj, x[0], x[1]]), coarse)
    v = _eval(e, msh, cells, (len(coarse), 3))
    dj, xs = v[..., 0], v[..., 1:]
    p0, p1, p2 = xs[:, 0], xs[:, 1], xs[:, 2]
    det0 = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p2[:, 0] - p0[:, 0]) * (
        p1[:, 1] - p0[:, 1]
    )
    X, Y = coarse[None, :, 0:1], coarse[None, :, 1:2]
    affine_x = p0[:, None] + X * (p1 - p0)[:, None] + Y * (p2 - p0)[:, None]
    diam = np.max([np.linalg.norm(a - b, axis=1) for a, b in ((p0, p1), (p1, p2), (p2, p0))], 0)
    dev = np.linalg.norm(xs - affine_x, axis=2).max(axis=1) if ncells else np.zeros(0)
    curved = np.flatnonzero((dev > 1e-9 * diam) | full)
    mins = dj.min(axis=1) if ncells else np.zeros(0)
    if len(curved):
        fine = reference_lattice(lattice)
        ef = fem.Expression(detj, fine)
        mins[curved] = np.minimum(mins[curved], _eval(ef, msh, cells[curved], (len(fine),)).min(1))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = mins / np.abs(det0)
    ratio = np.where(np.isfinite(ratio), ratio, -np.inf)
    edges = [p1 - p0, p2 - p1, p0 - p2]
    angles = []
    for a, b in ((0, 2), (1, 0), (2, 1)):  # angle at vertex k between edges leaving it
        u, w = edges[a], -edges[b]
        cosang = (u * w).sum(1) / (np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1))
        angles.append(np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0))))
    ang = np.column_stack(angles) if ncells else np.zeros((0, 3))
    centre = xs[:, :3].mean(axis=1)
    k = int(np.argmin(mins)) if ncells else -1
    kr = int(np.argmin(ratio)) if ncells else -1
    return {
        "min": float(mins.min()) if ncells else np.inf,
        "min_at": centre[k].tolist() if ncells else None,
        "ratio": float(ratio.min()) if ncells else np.inf,
        "ratio_at": centre[kr].tolist() if ncells else None,
        "bad": int((mins <= 0).sum()),
        "curved": len(curved),
        "min_angle": float(ang.min()) if ncells else np.inf,
        "max_angle": float(ang.max()) if ncells else -np.inf,
    }


def _facet_cells(topo: dmesh.Topology, facets: npt.NDArray) -> tuple[Int, Int]:
    """A cell of each facet and the facet's local index in it."""
    f2c = topo.connectivity(1, 2)
    cells = f2c.array[f2c.offsets[facets]]
    c2f = topo.connectivity(2, 1).array.reshape(-1, 3)
    local = np.argmax(c2f[cells] == np.asarray(facets)[:, None], axis=1)
    return cells.astype(np.int64), local.astype(np.int64)


def _boundary_integrals(
    msh: dmesh.Mesh, facets: npt.NDArray, boundary: du.Boundary
) -> dict[str, float]:
    """``int phi ds``, ``int |phi| ds``, length, max ``|phi|`` and bulge over facets (local)."""
    q = msh.geometry.cmaps[0].degree
    g, w = np.polynomial.legendre.leggauss(3)
    m = q + 1  # composite rule: |phi| has kinks at the q + 1 nodes
    t = ((np.arange(m)[:, None] + 0.5 * (g + 1)) / m).ravel()
    wt = np.tile(0.5 * w / m, m)
    pts = np.concatenate([o + t[:, None] * d for o, d in zip(_EDGE_ORIGIN, _EDGE_DIR)])
    x = ufl.SpatialCoordinate(msh)
    J = ufl.Jacobian(msh)
    e = fem.Expression(ufl.as_vector([x[0], x[1], J[0, 0], J[0, 1], J[1, 0], J[1, 1]]), pts)
    cells, local = _facet_cells(msh.topology, facets)
    out = {"signed": 0.0, "abs": 0.0, "length": 0.0, "dev": 0.0, "bulge": 0.0, "chord": 0.0}
    if not len(facets):
        return out
    v = _eval(e, msh, cells, (3, len(t), 6))[np.arange(len(cells)), local]  # (nf, nt, 6)
    xp = v[..., :2]
    jac = v[..., 2:].reshape(len(cells), len(t), 2, 2)
    dxdt = np.einsum("fpij,fj->fpi", jac, _EDGE_DIR[local])
    ds = np.linalg.norm(dxdt, axis=2) * wt
    phi = np.asarray(boundary.signed_distance(xp.reshape(-1, 2))).reshape(len(cells), len(t))
    vx = dmesh.entities_to_geometry(msh, 1, np.asarray(facets, dtype=np.int32))[:, :2]
    gx = msh.geometry.x[:, :2]
    chord = np.linalg.norm(gx[vx[:, 0]] - gx[vx[:, 1]], axis=1)
    devf = np.abs(phi).max(axis=1)
    out.update(
        signed=float((phi * ds).sum()),
        abs=float((np.abs(phi) * ds).sum()),
        length=float(ds.sum()),
        dev=float(devf.max()),
        bulge=float((devf / chord).max()),
        chord=float(chord.max()),
    )
    return out


def _components(comm: MPI.Comm, edges: Int) -> tuple[int, int]:
    """Connected components of a graph given by edges gathered on rank 0, and the number of
    nodes whose degree is not 2 (the graph is then not a set of closed simple curves)."""
    gathered = comm.gather(edges, root=0)
    result = (0, 0)
    if comm.rank == 0:
        e = np.unique(np.sort(np.concatenate(gathered), axis=1), axis=0)
        nodes, inv = np.unique(e.ravel(), return_inverse=True)
        inv = inv.reshape(-1, 2)
        n = len(nodes)
        graph = sp.coo_matrix((np.ones(len(inv)), (inv[:, 0], inv[:, 1])), shape=(n, n))
        ncomp = connected_components(graph, directed=False)[0] if n else 0
        degree = np.bincount(inv.ravel(), minlength=n)
        result = (int(ncomp), int((degree != 2).sum()))
    return comm.bcast(result, root=0)


def _pieces(msh: dmesh.Mesh) -> int:
    """Connected components of the cells of ``msh`` through shared facets (global)."""
    topo = msh.topology
    imc, imf = topo.index_map(2), topo.index_map(1)
    nc = imc.size_local
    c2f = topo.connectivity(2, 1).array.reshape(-1, 3)[:nc]
    fg = imf.local_to_global(c2f.ravel().astype(np.int32))
    cg = np.repeat(imc.local_range[0] + np.arange(nc), 3)
    ncg = imc.size_global
    # bipartite graph: cells 0..ncg-1, facets ncg + global facet index
    return _components(msh.comm, np.column_stack([cg, ncg + fg]).astype(np.int64))[0]


def check_mesh(
    mesh: dmesh.Mesh,
    facet_tags: dmesh.MeshTags,
    boundary: du.Boundary,
    exact_area: float,
    *,
    n_curves: int | None = None,
    n_pieces: int | None = 1,
    outer: bool | None = None,
    tol_area: float | None = None,
    tol_node: float | None = None,
    lattice: int = 30,
    full_lattice: bool = False,
    label: str = "",
) -> dict[str, Any]:
    """Measure a conforming mesh of the domain bounded by ``boundary`` and list its failures.

    Parameters
    ----------
    mesh
        Triangle mesh, any geometry degree ``q``.
    facet_tags
        Facet tags with :data:`~dolfinx_universal.IMMERSED` on Gamma_h and
        :data:`~dolfinx_universal.OUTER` on the background's boundary.
    boundary
        Gamma (signed distances).
    exact_area
        Area of Omega (independently computed).
    n_curves
        Expected number of closed curves of Gamma_h (not checked if None).
    n_pieces
        Expected number of connected pieces of the mesh (not checked if None).
    outer
        Whether facets tagged OUTER are expected (not checked if None).
    tol_area
        Absolute tolerance of ``|area_h - exact_area|``. Default:
        ``AREA_FACTOR * int |phi| ds + 1e-11 * extent^2`` on ``|area_h - exact_area - int phi
        ds|`` (see the module docstring).
    tol_node
        Largest ``|phi|`` at geometry nodes of immersed facets; default ``NODE_TOL * extent``.
    lattice
        Subdivisions per edge of the lattice for ``det J`` on non-affine cells.
    full_lattice
        Use the fine lattice on every cell, affine or not.
    label
        Prefix of the failure messages (e.g. the seed, kind and degree).

    Returns
    -------
    The measured numbers and ``"failures"``, a list of messages (empty: the mesh passed).
    Among them ``area_constant = |area_h - exact_area| / (L h_near^(q+1))`` (``h_near``: the
    longest immersed facet, ``L``: the length of Gamma_h), the constant of the a priori bound,
    for reference.
    """
    if mesh.geometry.dim != 2 or mesh.topology.dim != 2:
        raise ValueError("check_mesh needs a triangle mesh with 2D geometry (det J signed)")
    comm = mesh.comm
    topo = mesh.topology
    for a, b in ((1, 0), (1, 2), (2, 1), (2, 0)):
        topo.create_connectivity(a, b)
    q = mesh.geometry.cmaps[0].degree
    box = np.asarray(boundary.bounding_box(), dtype=np.float64)
    extent = float((box[1] - box[0]).max())
    nfo = topo.index_map(1).size_local
    failures: list[str] = []
    prefix = f"{label}: " if label else ""

    def fail(msg: str) -> None:
        failures.append(prefix + msg)

    # det J
    jl = _jacobians(mesh, lattice, full_lattice)
    min_detj, at = _gather_min(comm, jl["min"], jl["min_at"])
    min_ratio, ratio_at = _gather_min(comm, jl["ratio"], jl["ratio_at"])
    bad = comm.allreduce(jl["bad"])
    if min_detj <= 0:
        fail(
            f"{bad} cells with det J <= 0 (min {min_detj:.3g}, det J / det J_affine down to "
            f"{min_ratio:.3g}) near {_fmt(at)}"
        )

    # tags
    immersed = facet_tags.find(du.IMMERSED)
    outer_f = facet_tags.find(du.OUTER)
    exterior = dmesh.exterior_facet_indices(topo)
    untagged = comm.allreduce(int(np.setdiff1d(exterior, facet_tags.indices).size))
    owned_imm = immersed[immersed < nfo]
    interior_imm = comm.allreduce(int(np.setdiff1d(owned_imm, exterior).size))
    n_imm = comm.allreduce(int(owned_imm.size))
    n_out = comm.allreduce(int((outer_f < nfo).sum()))
    if untagged:
        fail(f"{untagged} exterior facets carry no tag")
    if interior_imm:
        fail(f"{interior_imm} interior facets are tagged IMMERSED")
    if outer is not None and (n_out > 0) != outer:
        fail(f"{n_out} facets tagged OUTER (expected {'some' if outer else 'none'})")
    if n_imm == 0:
        fail("no facet is tagged IMMERSED")

    # nodes on Gamma
    nodes = np.unique(dmesh.entities_to_geometry(mesh, 1, immersed.astype(np.int32)))
    xn = mesh.geometry.x[nodes, :2]
    phin = np.abs(boundary.signed_distance(xn)) if len(nodes) else np.zeros(0)
    k = int(np.argmax(phin)) if len(nodes) else -1
    node_dist, node_at = max(
        comm.allgather((float(phin.max()) if len(nodes) else 0.0, xn[k] if k >= 0 else None)),
        key=lambda vw: vw[0],
    )
    tol_node = NODE_TOL * extent if tol_node is None else tol_node
    if node_dist > tol_node:
        fail(
            f"geometry node of an immersed facet {node_dist:.3g} from Gamma (tolerance "
            f"{tol_node:.3g}) at {_fmt(node_at)}"
        )

    # area
    bi = _boundary_integrals(mesh, owned_imm, boundary)
    signed = comm.allreduce(bi["signed"])
    absint = comm.allreduce(bi["abs"])
    length = comm.allreduce(bi["length"])
    dev = comm.allreduce(bi["dev"], op=MPI.MAX)
    bulge = comm.allreduce(bi["bulge"], op=MPI.MAX)
    h_near = comm.allreduce(bi["chord"], op=MPI.MAX)
    area = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(mesh))))
    err = area - exact_area
    if tol_area is None:
        tol = AREA_FACTOR * absint + 1e-11 * extent**2
        if abs(err - signed) > tol:
            fail(
                f"area {area:.12g} vs exact {exact_area:.12g}: error {err:.3g} is not the "
                f"boundary defect int phi ds = {signed:.3g} (tolerance {tol:.3g}): cells "
                "missing or overlapping, or a wrong exact area"
            )
    else:
        tol = tol_area
        if abs(err) > tol:
            fail(f"area {area:.12g} vs exact {exact_area:.12g}: error {err:.3g} > {tol:.3g}")
    if bulge > BULGE:
        fail(f"an immersed facet strays {bulge:.3g} of its length from Gamma")

    # topology
    fv = topo.connectivity(1, 0).array.reshape(-1, 2)[immersed]
    gv = topo.index_map(0).local_to_global(fv.ravel().astype(np.int32)).reshape(-1, 2)
    n_loops, not_simple = _components(comm, gv.astype(np.int64))
    if not_simple:
        fail(
            f"Gamma_h is not a set of closed simple curves: {not_simple} vertices not on two "
            "immersed facets"
        )
    if n_curves is not None and n_loops != n_curves:
        fail(f"Gamma_h has {n_loops} loops, expected {n_curves}")
    pieces = _pieces(mesh)
    if n_pieces is not None and pieces != n_pieces:
        fail(f"the mesh has {pieces} connected pieces, expected {n_pieces}")

    return {
        "degree": int(q),
        "num_cells": int(topo.index_map(2).size_global),
        "num_curved_cells": comm.allreduce(jl["curved"]),
        "min_detJ": float(min_detj),
        "min_detJ_ratio": float(min_ratio),
        "min_detJ_ratio_at": ratio_at,
        "min_angle_deg": comm.allreduce(jl["min_angle"], op=MPI.MIN),
        "max_angle_deg": comm.allreduce(jl["max_angle"], op=MPI.MAX),
        "max_node_distance": float(node_dist),
        "area": float(area),
        "exact_area": float(exact_area),
        "area_error": float(err),
        "area_rel_error": float(abs(err) / abs(exact_area)) if exact_area else float(abs(err)),
        "area_constant": float(abs(err) / (length * h_near ** (q + 1))) if length else np.nan,
        "boundary_defect": float(signed),
        "boundary_defect_abs": float(absint),
        "area_tol": float(tol),
        "boundary_deviation": float(dev),
        "boundary_length": float(length),
        "h_near": float(h_near),
        "max_bulge": float(bulge),
        "n_immersed_facets": int(n_imm),
        "n_outer_facets": int(n_out),
        "n_loops": int(n_loops),
        "n_pieces": int(pieces),
        "failures": failures,
    }


def check_domain_mesh(mesh: dmesh.Mesh, facet_tags: dmesh.MeshTags, d: Any, label: str) -> dict:
    """:func:`check_mesh` of a mesh of the random domain ``d`` (``random_domains``): its
    exact area, curves and pieces, no OUTER facets (the domains are bounded)."""
    return check_mesh(
        mesh,
        facet_tags,
        d.boundary,
        d.exact_area,
        n_curves=d.n_curves,
        n_pieces=d.n_pieces,
        outer=False,
        label=label,
    )
