"""Checks of conforming tetrahedral meshes that do not use the package's own checks.

:func:`check_surface_mesh` measures a straight (degree-1) DOLFINx tetrahedral mesh of a
solid Omega with NumPy, SciPy, UFL and DOLFINx only; the solid's definition comes from the
test's own level sets (a :class:`random_surfaces.RandomSurface`: ``signed_distance`` and
``normal``, ``phi / |grad phi|`` of private copies of the shapes), never from the package:

* Cells: every owned tetrahedron has a positive signed volume
  ``det(x1 - x0, x2 - x0, x3 - x0) / 6`` and is not degenerate: its normalised volume
  ``6 sqrt(2) V / l_max^3`` (1 for the regular tetrahedron) is above :data:`DEGENERATE`.
  Dihedral angles (between the outward normals of the faces, per edge) are measured.
* Tags: every exterior facet is tagged :data:`~dolfinx_universal.IMMERSED` and every
  IMMERSED facet is exterior (a closed Gamma inside the box: no OUTER facet is expected).
* The IMMERSED faces, each oriented away from its tetrahedron and gathered from every rank
  by global vertex index, form a closed, consistently oriented 2-manifold: every directed
  edge occurs once and its reverse once (each edge in exactly two faces, in opposite
  directions), and the faces around each vertex form one fan (the "corners" of a vertex
  are connected through shared edges). Per connected component of the faces ``V - E + F``
  is computed; the sorted list must equal the solid's (container and bodies), so the total
  is its Euler characteristic. The divergence theorem on these faces
  (``sum (a . b x c) / 6``) must give the assembled volume to rounding: the faces are
  oriented out of the mesh and bound all of it.
* Vertices of IMMERSED faces are on Gamma: ``|phi| <= NODE_TOL * extent``.
* Volume ``V_h = assemble(1 dx)`` against the exact volume ``V``, two ways:

  - a priori: for a flat triangle ``T`` with its vertices on Gamma, ``|phi|`` on ``T`` is
    the linear interpolation error of the surface seen as a graph over ``T``: at most
    ``kappa_max rho_T^2 / 2`` with ``rho_T`` the radius of the smallest ball containing ``T``
    (Waldron's bound for linear interpolation on simplices), and ``rho_T <= h_T / sqrt(3)``
    (Jung's theorem), so ``|phi| <= kappa_max h_T^2 / 6`` to leading order and
    ``|V_h - V| <= int_{Gamma_h} |phi| <= A_h kappa_max h_f^2 / 6`` (``A_h`` the area of
    Gamma_h, ``h_f`` its longest edge). The check allows :data:`APRIORI_C` ``= 1/3``, twice
    the leading constant, for the higher-order terms (the graph's slope and
    ``h kappa <= 1/2``). The measured ``volume_constant = |V_h - V| / (A_h kappa_max
    h_f^2)`` is reported (about 0.02-0.06 on the fuzz domains).
  - the boundary defect: Omega_h and Omega differ by the region between Gamma_h and Gamma,
    whose signed volume is ``D = int_{Gamma_h} phi (n . nu_h) dS`` up to a relative
    ``O(|phi| kappa)`` (``n``: normal of Gamma, ``nu_h``: of the face); ``D`` is integrated
    by a 16-point Gauss rule on every face. ``|V_h - V - D|`` must be at most
    :data:`DEFECT_FACTOR` ``int |phi| dS``: a mesh with a missing or doubled cell fails it
    however fine the mesh is (a cell changes ``V_h`` by ``h^3`` and ``D`` by nothing).

  Both add the stated error of the exact volume and ``1e-11 extent^3``.

Collective; every rank returns the same dictionary.

:func:`check_curved_surface_mesh` then measures the degree-q mesh with the same vertices
and topology (basix and DOLFINx only): ``det J`` sampled on every curved cell against the
package's proven bound, the nodes of the immersed faces on Gamma, and the volume.
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

__all__ = [
    "active_node_gap",
    "check_curved_surface_mesh",
    "check_surface_mesh",
    "dihedral_angles",
    "signed_volumes",
    "surface_topology",
]

Float = npt.NDArray[np.float64]
Int = npt.NDArray[np.int64]

NODE_TOL = 1e-10
"""Largest ``|phi|`` of a vertex of an IMMERSED face, relative to the extent of Gamma."""
DEGENERATE = 1e-6
"""Smallest normalised volume ``6 sqrt(2) V / l_max^3`` of a tetrahedron."""
APRIORI_C = 1.0 / 3.0
"""Constant of the a priori volume bound ``|V_h - V| <= C A_h kappa_max h_f^2``."""
DEFECT_FACTOR = 0.25
"""Allowed mismatch ``|V_h - V - D|`` relative to ``int |phi| dS``."""
DIVERGENCE_RTOL = 1e-9
"""Relative agreement of the divergence-theorem volume of the faces and the assembled one."""

# 16-point Gauss rule on the reference triangle {(s, t): s, t >= 0, s + t <= 1} (collapsed
# square; exact for polynomials of degree 7), weights summing to 1/2.
_g, _w = np.polynomial.legendre.leggauss(4)
_u, _v = 0.5 * (_g + 1), 0.5 * _w
_TRI_S = np.repeat(_u, 4)
_TRI_T = np.tile(_u, 4) * (1 - _TRI_S)
_TRI_W = np.outer(_v, _v).ravel() * (1 - _TRI_S)


def signed_volumes(p: Float) -> Float:
    """Signed volumes ``(n,)`` of tetrahedra with corners ``p (n, 4, 3)``."""
    a, b, c = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
    return np.einsum("ni,ni->n", a, np.cross(b, c)) / 6.0


def dihedral_angles(p: Float) -> Float:
    """The six dihedral angles (degrees) ``(n, 6)`` of tetrahedra ``p (n, 4, 3)``.

    The angle at the edge shared by the faces opposite corners ``i`` and ``j`` is
    ``pi - angle(n_i, n_j)`` with ``n_i`` the outward normal of the face opposite ``i``
    (orientation-independent: both normals flip together).
    """
    normals = []
    for i in range(4):
        a, b, c = (p[:, k] for k in range(4) if k != i)
        n = np.cross(b - a, c - a)
        n *= np.sign(np.einsum("ni,ni->n", n, a - p[:, i]))[:, None]  # away from corner i
        normals.append(n / np.linalg.norm(n, axis=1)[:, None])
    out = []
    for i in range(4):
        for j in range(i + 1, 4):
            cos = np.clip(np.einsum("ni,ni->n", normals[i], normals[j]), -1.0, 1.0)
            out.append(180.0 - np.degrees(np.arccos(cos)))
    return np.column_stack(out) if len(p) else np.zeros((0, 6))


def _normalised_volumes(p: Float, vol: Float) -> Float:
    edges = [p[:, j] - p[:, i] for i in range(4) for j in range(i + 1, 4)]
    lmax = np.max([np.linalg.norm(e, axis=1) for e in edges], axis=0)
    return 6 * np.sqrt(2) * vol / lmax**3


def surface_topology(g: Int) -> dict[str, Any]:
    """Topology of oriented triangles given by global vertex indices ``g (F, 3)``.

    Returns ``closed_oriented`` (every directed edge once and its reverse once),
    ``manifold_vertices`` (the faces around every vertex form a single fan), the number of
    ``components`` (faces connected through edges), their Euler characteristics ``euler``
    (sorted) and the totals ``V``, ``E``, ``F``.
    """
    F = len(g)
    if F == 0:
        return {"closed_oriented": False, "manifold_vertices": False, "components": 0,
                "euler": [], "V": 0, "E": 0, "F": 0}  # fmt: skip
    directed = np.concatenate([g[:, [0, 1]], g[:, [1, 2]], g[:, [2, 0]]])  # (3F, 2)
    face_of = np.tile(np.arange(F), 3)
    und, inv, cnt = np.unique(
        np.sort(directed, axis=1), axis=0, return_inverse=True, return_counts=True
    )
    inv = inv.ravel()
    n_directed = len(np.unique(directed, axis=0))
    closed = bool(n_directed == len(directed) and (cnt == 2).all())
    # the two directed edges of each edge that has two (consecutive once sorted by edge)
    order = np.argsort(inv, kind="stable")
    pairs = order[cnt[inv[order]] == 2].reshape(-1, 2)
    fa, fb = face_of[pairs[:, 0]], face_of[pairs[:, 1]]
    adj = sp.coo_matrix((np.ones(len(fa)), (fa, fb)), shape=(F, F))
    ncomp, lab = connected_components(adj, directed=False)
    # corners (face, vertex): joined across each edge at both of its end vertices
    verts, vinv = np.unique(g.ravel(), return_inverse=True)
    corner = np.arange(3 * F).reshape(F, 3)  # corner of face f at its local vertex k
    k_of = np.repeat(np.arange(3), F)  # directed edge e runs from local vertex k to k + 1
    ca = cb = np.zeros(0, dtype=np.int64)
    if closed:  # edge t is the reverse of edge s: join the corners at both ends
        s, t = pairs[:, 0], pairs[:, 1]
        fs, ft, ks, kt = face_of[s], face_of[t], k_of[s], k_of[t]
        ca = np.concatenate([corner[fs, ks], corner[fs, (ks + 1) % 3]])
        cb = np.concatenate([corner[ft, (kt + 1) % 3], corner[ft, kt]])
    cg = sp.coo_matrix((np.ones(len(ca)), (ca, cb)), shape=(3 * F, 3 * F))
    _, clab = connected_components(cg, directed=False)
    # a vertex is manifold when all its corners are in one corner component
    vert_of_corner = vinv.reshape(F, 3).ravel()
    per_vertex = np.unique(np.column_stack([vert_of_corner, clab]), axis=0)
    manifold = bool(closed and len(per_vertex) == len(verts))
    euler = []
    for c in range(ncomp):
        fc = g[lab == c]
        ec = und[np.unique(inv[np.concatenate([lab == c] * 3)])]
        euler.append(int(len(np.unique(fc)) - len(ec) + len(fc)))
    return {
        "closed_oriented": closed,
        "manifold_vertices": manifold,
        "components": int(ncomp),
        "euler": sorted(euler),
        "V": int(len(verts)),
        "E": int(len(und)),
        "F": int(F),
    }


def _owned_surface(msh: dmesh.Mesh, faces: npt.NDArray, xv: Float) -> tuple[Int, Float]:
    """Owned IMMERSED faces oriented away from their tetrahedron: global vertex indices
    ``(f, 3)`` and corner coordinates ``(f, 3, 3)`` (local to this rank)."""
    topo = msh.topology
    f2v = topo.connectivity(2, 0).array.reshape(-1, 3)
    f2c = topo.connectivity(2, 3)
    c2v = topo.connectivity(3, 0).array.reshape(-1, 4)
    tri = f2v[faces].copy()
    cell = f2c.array[f2c.offsets[faces]]
    cv = c2v[cell]
    fourth = cv[~(cv[:, :, None] == tri[:, None, :]).any(axis=2)]
    a, b, c = xv[tri[:, 0]], xv[tri[:, 1]], xv[tri[:, 2]]
    flip = np.einsum("ni,ni->n", np.cross(b - a, c - a), a - xv[fourth]) < 0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    g = topo.index_map(0).local_to_global(tri.ravel().astype(np.int32)).reshape(-1, 3)
    return g.astype(np.int64), xv[tri]


def _defect(d: Any, pts: Float) -> dict[str, float]:
    """``int phi (n . nu) dS``, ``int |phi| dS``, area and longest edge of faces ``pts``."""
    if not len(pts):
        return {"signed": 0.0, "abs": 0.0, "area": 0.0, "edge": 0.0}
    a, b, c = pts[:, 0], pts[:, 1], pts[:, 2]
    cr = np.cross(b - a, c - a)
    area2 = np.linalg.norm(cr, axis=1)  # twice the area
    nu = cr / area2[:, None]
    q = (
        a[:, None]
        + _TRI_S[None, :, None] * (b - a)[:, None]
        + _TRI_T[None, :, None] * (c - a)[:, None]
    )
    qf = q.reshape(-1, 3)
    phi = d.signed_distance(qf).reshape(len(pts), -1)
    cos = np.einsum("nqi,ni->nq", d.normal(qf).reshape(len(pts), -1, 3), nu)
    w = _TRI_W[None] * area2[:, None]
    edges = np.max([np.linalg.norm(u, axis=1) for u in (b - a, c - b, a - c)], axis=0)
    return {
        "signed": float((w * phi * cos).sum()),
        "abs": float((w * np.abs(phi)).sum()),
        "area": float(0.5 * area2.sum()),
        "edge": float(edges.max()),
    }


def _pieces(msh: dmesh.Mesh) -> int:
    """Connected components of the cells through shared facets (global; on rank 0)."""
    topo = msh.topology
    imc, imf = topo.index_map(3), topo.index_map(2)
    nc = imc.size_local
    c2f = topo.connectivity(3, 2).array.reshape(-1, 4)[:nc]
    fg = imf.local_to_global(c2f.ravel().astype(np.int32)).astype(np.int64)
    cg = np.repeat(imc.local_range[0] + np.arange(nc, dtype=np.int64), 4)
    edges = msh.comm.gather(np.column_stack([cg, imc.size_global + fg]), root=0)
    n = 0
    if msh.comm.rank == 0:
        e = np.concatenate(edges)
        m = imc.size_global + imf.size_global
        graph = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(m, m))
        _, lab = connected_components(graph, directed=False)
        n = len(np.unique(lab[: imc.size_global]))
    return int(msh.comm.bcast(n, root=0))


def check_surface_mesh(
    mesh: dmesh.Mesh,
    facet_tags: dmesh.MeshTags,
    d: Any,
    label: str = "",
    *,
    min_dihedral: float | None = None,
    n_pieces: int | None = 1,
) -> dict[str, Any]:
    """Measure a conforming tetrahedral mesh of the solid ``d`` and list its failures.

    Parameters
    ----------
    mesh
        Straight tetrahedral mesh (degree 1).
    facet_tags
        IMMERSED on Gamma_h (OUTER facets are reported as failures).
    d
        The solid: ``signed_distance(x)``, ``normal(x)``, ``exact_volume``,
        ``volume_error``, ``euler_characteristic``, ``component_euler``, ``extent``,
        ``max_curvature`` (a :class:`random_surfaces.RandomSurface`).
    label
        Prefix of the failure messages.
    min_dihedral
        Fail below this smallest dihedral angle (degrees); None: measure only.
    n_pieces
        Expected connected pieces of the mesh (None: not checked).

    Returns
    -------
    The measured numbers and ``"failures"`` (empty: the mesh passed).
    """
    if mesh.topology.dim != 3 or mesh.geometry.dim != 3:
        raise ValueError("check_surface_mesh needs a tetrahedral mesh in 3D")
    if mesh.geometry.cmaps[0].degree != 1:
        raise ValueError("check_surface_mesh checks straight (degree-1) meshes")
    comm = mesh.comm
    topo = mesh.topology
    for a, b in ((2, 0), (2, 3), (3, 0), (3, 2)):
        topo.create_connectivity(a, b)
    failures: list[str] = []
    prefix = f"{label}: " if label else ""

    def fail(msg: str) -> None:
        failures.append(prefix + msg)

    # vertex coordinates by topological vertex index (degree 1: one node per vertex)
    c2v = topo.connectivity(3, 0).array.reshape(-1, 4)
    v2n = np.empty(topo.index_map(0).size_local + topo.index_map(0).num_ghosts, dtype=np.int64)
    v2n[c2v] = mesh.geometry.dofmaps[0][:, :4]
    xv = mesh.geometry.x[v2n]
    extent = float(d.extent)

    # cells
    nc = topo.index_map(3).size_local
    p = xv[c2v[:nc]]
    vol = signed_volumes(p)
    nvol = _normalised_volumes(p, vol) if nc else np.zeros(0)
    ang = dihedral_angles(p)
    inverted = comm.allreduce(int((vol <= 0).sum()))
    degenerate = comm.allreduce(int((nvol <= DEGENERATE).sum()))
    min_nvol = comm.allreduce(float(nvol.min()) if nc else np.inf, op=MPI.MIN)
    dmin = comm.allreduce(float(ang.min()) if nc else np.inf, op=MPI.MIN)
    dmax = comm.allreduce(float(ang.max()) if nc else -np.inf, op=MPI.MAX)
    if inverted:
        fail(f"{inverted} tetrahedra with signed volume <= 0")
    if degenerate:
        fail(f"{degenerate} degenerate tetrahedra (normalised volume down to {min_nvol:.3g})")
    if min_dihedral is not None and dmin < min_dihedral:
        fail(f"smallest dihedral angle {dmin:.3f} deg < {min_dihedral} deg")

    # tags
    nfo = topo.index_map(2).size_local
    immersed = facet_tags.find(du.IMMERSED)
    n_outer = comm.allreduce(int((facet_tags.find(du.OUTER) < nfo).sum()))
    exterior = dmesh.exterior_facet_indices(topo)
    owned_imm = immersed[immersed < nfo]
    ext_not_imm = comm.allreduce(int(np.setdiff1d(exterior[exterior < nfo], owned_imm).size))
    imm_interior = comm.allreduce(int(np.setdiff1d(owned_imm, exterior).size))
    if n_outer:
        fail(f"{n_outer} facets tagged OUTER: Gamma is closed inside the box")
    if ext_not_imm:
        fail(f"{ext_not_imm} exterior facets are not tagged IMMERSED")
    if imm_interior:
        fail(f"{imm_interior} interior facets are tagged IMMERSED")

    # the immersed surface, gathered
    g_loc, pts_loc = _owned_surface(mesh, owned_imm, xv)
    g = np.concatenate(comm.allgather(g_loc))
    pts = np.concatenate(comm.allgather(pts_loc))
    topo_s = surface_topology(g)
    if not topo_s["closed_oriented"]:
        fail(
            "the IMMERSED faces are not a closed consistently oriented surface (some edge is "
            "not in exactly two faces of opposite directions)"
        )
    elif not topo_s["manifold_vertices"]:
        fail("the IMMERSED faces meet at a non-manifold vertex (more than one fan)")
    chi = topo_s["V"] - topo_s["E"] + topo_s["F"]
    want = sorted(int(e) for e in d.component_euler)
    if topo_s["euler"] != want or chi != d.euler_characteristic:
        fail(
            f"Gamma_h has {topo_s['components']} components of Euler characteristics "
            f"{topo_s['euler']} (total {chi}); expected {want} (total {d.euler_characteristic})"
        )

    # vertices on Gamma
    if len(pts):
        xs = np.unique(pts.reshape(-1, 3), axis=0)
        dist = np.abs(d.signed_distance(xs))
        node = float(dist.max())
        node_at = xs[int(np.argmax(dist))].tolist()
    else:
        node, node_at = 0.0, None
    if node > NODE_TOL * extent:
        fail(f"a vertex of an IMMERSED face is {node:.3g} from Gamma at {node_at}")

    # volume
    v_h = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * ufl.dx(mesh))), op=MPI.SUM)
    o = pts.reshape(-1, 3).mean(axis=0) if len(pts) else np.zeros(3)
    q = pts - o
    enclosed = float(np.einsum("ni,ni->n", q[:, 0], np.cross(q[:, 1], q[:, 2])).sum() / 6)
    if abs(enclosed - v_h) > DIVERGENCE_RTOL * abs(v_h) + 1e-13 * extent**3:
        fail(
            f"the oriented IMMERSED faces enclose {enclosed:.12g}, the cells {v_h:.12g}: "
            "cells missing or overlapping, or faces oriented into the mesh"
        )
    dl = _defect(d, pts_loc)
    signed = comm.allreduce(dl["signed"])
    absint = comm.allreduce(dl["abs"])
    area = comm.allreduce(dl["area"])
    h_f = comm.allreduce(dl["edge"], op=MPI.MAX)
    err = v_h - d.exact_volume
    slack = d.volume_error + 1e-11 * extent**3
    tol_defect = DEFECT_FACTOR * absint + slack
    if abs(err - signed) > tol_defect:
        fail(
            f"volume {v_h:.12g} vs exact {d.exact_volume:.12g}: error {err:.3g} is not the "
            f"boundary defect int phi dS = {signed:.3g} (tolerance {tol_defect:.3g})"
        )
    bound = area * d.max_curvature * h_f**2
    tol_apriori = APRIORI_C * bound + slack
    if abs(err) > tol_apriori:
        fail(
            f"volume error {err:.3g} above the a priori bound {tol_apriori:.3g} "
            f"({APRIORI_C:.3g} A_h kappa_max h_f^2, A_h = {area:.4g}, h_f = {h_f:.3g})"
        )

    pieces = _pieces(mesh) if n_pieces is not None else None
    if n_pieces is not None and pieces != n_pieces:
        fail(f"the mesh has {pieces} connected pieces, expected {n_pieces}")

    return {
        "failures": failures,
        "num_cells": int(topo.index_map(3).size_global),
        "inverted": inverted,
        "min_normalised_volume": min_nvol,
        "min_dihedral_deg": dmin,
        "max_dihedral_deg": dmax,
        "surface_faces": topo_s["F"],
        "surface_components": topo_s["components"],
        "surface_euler": topo_s["euler"],
        "max_node_distance": node,
        "volume": float(v_h),
        "exact_volume": float(d.exact_volume),
        "volume_error": float(err),
        "volume_rel_error": float(abs(err) / abs(d.exact_volume)),
        "volume_constant": float(abs(err) / bound) if bound > 0 else np.nan,
        "boundary_defect": signed,
        "boundary_defect_abs": absint,
        "surface_area": area,
        "h_face": h_f,
        "pieces": pieces,
    }


AFFINE_TOL = 1e-12
"""A cell is curved when a geometry node is farther than this (relative to the extent of
Gamma) from the affine image of its vertices: DOLFINx writes the nodes of an affine cell
to a few ulps of the coordinates, and a curved cell's nodes move by ``O(kappa h^2)``."""
CERTIFICATE_TOL = 1e-9
"""The certificate's proven lower bound of ``det J / det J_straight`` may exceed the sampled
minimum by this much: both are computed in floating point, by different formulas
(Bernstein coefficients against the Jacobian at lattice points), and agree to about 1e-13
where the minimum sits at a lattice point (a vertex, often); 1e-9 is far above that and far
below any real defect of the proof (a bound above a sampled value by 1e-3 or more)."""


def check_curved_surface_mesh(
    mesh: dmesh.Mesh,
    facet_tags: dmesh.MeshTags,
    d: Any,
    straight: dict[str, Any],
    certificate_ratio: float | None = None,
    label: str = "",
) -> dict[str, Any]:
    """Measure a curved (degree ``q >= 2``) tetrahedral mesh of the solid ``d``; list its failures.

    The straight mesh with the same vertices and topology is checked first by
    :func:`check_surface_mesh` (its result is ``straight``): cells, tags, the closed
    oriented Gamma_h, pieces. The degree-q geometry is then measured with basix and
    DOLFINx only, never with the package's own Jacobian code:

    * Jacobians: every owned cell with a node off the affine image of its vertices
      (:data:`AFFINE_TOL`) is sampled on the equispaced lattice of order ``3 q`` (its
      vertices, edges and faces included); ``det J / det J_straight`` must be positive at
      every sample (a sample is no proof, but an inverted cell of a fuzz domain would show),
      and the package's proven lower bound ``certificate_ratio`` must not exceed the
      sampled minimum (:data:`CERTIFICATE_TOL`). The nodes are tabulated with basix's
      Lagrange element of the mesh's coordinate element variant, checked against
      DOLFINx's ``push_forward`` on a few cells first (the node order).
    * Every geometry node of an IMMERSED face lies on Gamma: ``|phi| <= NODE_TOL * extent``.
    * Volume: ``|V_h - V|`` (quadrature of degree ``3 q``: ``det J`` has degree ``3 (q -
      1)``) must stay within the straight mesh's a priori bound (:data:`APRIORI_C`
      ``A_h kappa_max h_f^2``): a node placed or ordered wrongly changes the volume by
      ``O(h^3)`` per cell. The ratio of the straight mesh's volume error to this one is
      reported (the gain of the curved geometry).

    Collective; every rank returns the same dictionary.
    """
    import basix

    cmap = mesh.geometry.cmaps[0]
    q = int(cmap.degree)
    if mesh.topology.dim != 3 or q < 2:
        raise ValueError("check_curved_surface_mesh checks curved (degree >= 2) tetrahedra")
    comm = mesh.comm
    failures: list[str] = []
    prefix = f"{label}: " if label else ""
    extent = float(d.extent)
    el = basix.create_element(
        basix.ElementFamily.P,
        basix.CellType.tetrahedron,
        q,
        basix.LagrangeVariant(int(cmap.variant)),
    )
    nc = mesh.topology.index_map(3).size_local
    x = mesh.geometry.x
    nodes = x[mesh.geometry.dofmaps[0][:nc]]  # (nc, ndofs, 3)
    ref = el.points  # (ndofs, 3); dofs 0-3 at the vertices
    lam = np.column_stack([1.0 - ref.sum(axis=1), ref])  # barycentric
    affine = np.einsum("nk,ckj->cnj", lam, nodes[:, :4])
    off = np.abs(nodes - affine).max(axis=(1, 2)) if nc else np.zeros(0)
    curved = np.flatnonzero(off > AFFINE_TOL * extent)
    # the node order: basix's basis against DOLFINx's push-forward
    if len(curved):
        probe = basix.create_lattice(
            basix.CellType.tetrahedron, 2, basix.LatticeType.equispaced, True
        )
        phi = el.tabulate(0, probe)[0, :, :, 0]
        for c in curved[:3]:
            mine = phi @ nodes[c]
            theirs = cmap.push_forward(probe, nodes[c])
            if not np.allclose(mine, theirs, rtol=0.0, atol=1e-12 * extent):
                raise RuntimeError("basix's Lagrange basis does not match the coordinate element")
    samples = basix.create_lattice(
        basix.CellType.tetrahedron, 3 * q, basix.LatticeType.equispaced, True
    )
    dphi = el.tabulate(1, samples)[1:4, :, :, 0]  # (3, npts, ndofs)
    ratio_min = np.inf
    where = None
    for start in range(0, len(curved), 2000):
        cells = curved[start : start + 2000]
        xc = nodes[cells]
        jac = np.einsum("cki,jpk->cpij", xc, dphi)  # d x_i / d X_j
        det = np.linalg.det(jac)
        e = xc[:, 1:4] - xc[:, :1]  # rows: the straight cell's edges from vertex 0
        det0 = np.linalg.det(np.transpose(e, (0, 2, 1)))
        r = det / det0[:, None]
        k = int(np.argmin(r.min(axis=1)))
        if r[k].min() < ratio_min:
            ratio_min = float(r[k].min())
            where = xc[k, :4].mean(axis=0).tolist()
    ratio_min = comm.allreduce(ratio_min, op=MPI.MIN)
    n_curved = comm.allreduce(len(curved))
    if ratio_min <= 0.0:
        fail_at = [w for w in comm.allgather(where) if w is not None]
        failures.append(
            prefix + f"a curved tetrahedron is inverted: sampled det J / det J_straight = "
            f"{ratio_min:.3g} (near {fail_at[0] if fail_at else '?'})"
        )
    if (
        certificate_ratio is not None
        and n_curved
        and certificate_ratio > ratio_min + CERTIFICATE_TOL
    ):
        failures.append(
            prefix + f"the certificate's proven det J ratio {certificate_ratio:.6g} exceeds the "
            f"sampled minimum {ratio_min:.6g}"
        )

    # nodes of the immersed faces on Gamma
    nfo = mesh.topology.index_map(2).size_local
    imm = facet_tags.find(du.IMMERSED)
    imm = imm[imm < nfo]
    mesh.topology.create_connectivity(2, 3)
    face_nodes = np.unique(dmesh.entities_to_geometry(mesh, 2, imm)) if len(imm) else []
    dist = np.abs(d.signed_distance(x[face_nodes])) if len(face_nodes) else np.zeros(0)
    node = comm.allreduce(float(dist.max()) if len(dist) else 0.0, op=MPI.MAX)
    if node > NODE_TOL * extent:
        failures.append(prefix + f"a node of an IMMERSED face is {node:.3g} from Gamma")

    # volume
    dx = ufl.dx(mesh, metadata={"quadrature_degree": 3 * q})
    v_h = comm.allreduce(fem.assemble_scalar(fem.form(1.0 * dx)), op=MPI.SUM)
    err = v_h - d.exact_volume
    slack = d.volume_error + 1e-11 * extent**3
    bound = APRIORI_C * straight["surface_area"] * d.max_curvature * straight["h_face"] ** 2
    if abs(err) > bound + slack:
        failures.append(
            prefix + f"degree-{q} volume error {err:.3g} above the straight mesh's a priori "
            f"bound {bound + slack:.3g}"
        )
    return {
        "failures": failures,
        "degree": q,
        "curved_cells": n_curved,
        "min_sampled_jacobian_ratio": float(ratio_min) if n_curved else 1.0,
        "max_node_distance": node,
        "volume_error": float(err),
        "volume_rel_error": float(abs(err) / abs(d.exact_volume)),
        "volume_gain": float(abs(straight["volume_error"]) / abs(err)) if err else np.inf,
    }


def active_node_gap(md: Any, cm: Any, msh: dmesh.Mesh) -> tuple[bool, float]:
    """Compare a ``MovingDomain`` after an update with a fresh conform of the same position.

    ``cm`` is ``md.universal.conform(boundary)``, ``msh`` its mesh or its curved mesh.
    Returns whether the owned active cells of ``md`` are the owned cells ``cm`` keeps, and
    (where they are) the largest difference of their geometry nodes from those of ``msh``
    (process-local; ``inf`` where the cells differ).
    """
    n = md.mesh.topology.index_map(3).size_local
    kept_n = cm.mesh.topology.index_map(3).size_local
    active = np.sort(md.active_cells[md.active_cells < n])
    kept = np.sort(cm.cell_map[:kept_n])
    if not np.array_equal(active, kept):
        return False, np.inf
    if not kept_n:
        return True, 0.0
    x_md = md.mesh.geometry.x[md.mesh.geometry.dofmaps[0][kept]]
    x_new = msh.geometry.x[msh.geometry.dofmaps[0][:kept_n]]
    order = np.argsort(cm.cell_map[:kept_n])
    return True, float(np.abs(x_md - x_new[order]).max())
