"""Normal or tangential component constraints on a curved boundary, by a local change of basis.

A vector field ``u`` (a blocked Lagrange space, or the vector part of a mixed space) is
constrained at the boundary nodes of a tagged boundary::

    u . T = g   (component="tangential")     or     u . N = g   (component="normal")

At each constrained node the two Cartesian unknowns are rotated into normal and tangential
ones: ``u = R y`` with ``R`` orthogonal and block diagonal (identity away from the boundary,
``[N T]`` at constrained nodes). The solver assembles ``A`` and ``b`` as usual, forms
``R^T A R`` and ``R^T b``, imposes the constrained rotated component (and any ordinary
Dirichlet conditions) symmetrically, solves, and rotates back. The constraint then holds to
rounding at every node.

Two choices of the frame ``(N, T)``:

* ``tangent="true"``: the exact normal and tangent of Gamma at the closest point of each
  boundary node (the nodes lie on Gamma for the isoparametric maps). This is the right
  condition for a curved boundary.
* ``tangent="discrete"``: the frame of the mesh boundary, from the derivative of each
  boundary facet's parametrisation at the node. A node shared by two facets whose frames
  differ (a corner of a straight or piecewise-polynomial boundary) receives the condition of
  *both* facets, which fixes both components there. This reproduces the classical mistake
  that makes simply supported plates on polygonal approximations converge to a wrong
  solution (the Babuska paradox and its Reissner-Mindlin relatives).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

from mpi4py import MPI
from petsc4py import PETSc

import basix
import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem, la
from dolfinx.fem import petsc as fem_petsc

from dolfinx_universal.conforming.universal import IMMERSED
from dolfinx_universal.core.arrays import Float, rot90
from dolfinx_universal.core.collective import collective_call
from dolfinx_universal.curved.maps import CurvedMesh, boundary_dof_data

__all__ = ["ConstrainedNodes", "SlipConstraint", "facet_frames"]

Value = float | Callable[[Float], npt.ArrayLike]

DEFAULT_PETSC_OPTIONS = {
    "ksp_type": "preonly",
    "pc_type": "lu",
    "pc_factor_mat_solver_type": "mumps",
}
"""Direct solve with MUMPS."""

_counter = itertools.count()


@dataclass
class ConstrainedNodes:
    """The constrained nodes owned by this process (all arrays are process-local).

    A node is *single* when it carries one condition ``u . c = g`` (``c`` the tangent or the
    normal of the chosen frame) and *double* when the frames of its two boundary facets differ
    (``tangent="discrete"`` only): both conditions then hold, and ``u = u0`` is fixed there.
    """

    blocks: npt.NDArray[np.int32]
    """Block (node) indices in the collapsed vector space, owned, ``(n,)``."""
    dofs: npt.NDArray[np.int32]
    """Local dof indices of the two components in the parent space, ``(n, 2)``."""
    x: Float
    """Points at which the frame and ``g`` are evaluated, ``(n, 2)``: the closest points of
    Gamma (``"true"``) or the node coordinates (``"discrete"``)."""
    normal: Float
    """Unit normal of the frame, ``(n, 2)`` (for double nodes: their mean direction)."""
    tangent: Float
    """Unit tangent of the frame, the normal rotated by +90 degrees, ``(n, 2)``."""
    value: Float
    """Prescribed value ``g`` of the constrained component, ``(n,)``."""
    double: npt.NDArray[np.bool_]
    """Nodes where two different facet conditions fix both components, ``(n,)``."""
    u0: Float
    """Fixed vector at double nodes (undefined elsewhere), ``(n, 2)``."""


def facet_frames(
    V: fem.FunctionSpace, facets: npt.NDArray[np.int32]
) -> tuple[npt.NDArray[np.int32], Float]:
    """Outward unit normal of the discrete boundary at the nodes of each boundary facet.

    The normal of facet ``f`` at a node with reference coordinates ``X`` is
    ``J(X)^{-T} n_ref`` (normalised), ``J`` the Jacobian of the cell's coordinate map and
    ``n_ref`` the reference facet normal: the normal of the facet's own parametrisation, exact
    for curved (degree-q) facets. The tangent is this normal rotated by +90 degrees.

    Parameters
    ----------
    V
        A Lagrange space (scalar or blocked) whose nodes are wanted, not a subspace.
    facets
        Process-local exterior facet indices, ``(m,)``.

    Returns
    -------
    blocks
        Process-local block (node) indices of the closure nodes of each facet, ``(m, k)``
        (``k`` nodes per facet: two vertices and the edge-interior ones).
    normals
        Outward unit normals at those nodes, ``(m, k, 2)``.
    """
    msh = V.mesh
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim - 1, tdim)
    msh.topology.create_connectivity(tdim, tdim - 1)
    f2c = msh.topology.connectivity(tdim - 1, tdim)
    c2f = msh.topology.connectivity(tdim, tdim - 1).array.reshape(-1, 3)
    facets = np.asarray(facets, dtype=np.int32)
    layout = V.dofmap.dof_layout
    closure = np.array([layout.entity_closure_dofs(tdim - 1, i) for i in range(3)])
    k = closure.shape[1]
    if len(facets) == 0:
        return np.zeros((0, k), dtype=np.int32), np.zeros((0, k, 2))
    cells = f2c.array[f2c.offsets[facets]]
    local = np.argmax(c2f[cells] == facets[:, None], axis=1)

    cmap = msh.geometry.cmaps[0]
    geom = basix.create_element(
        basix.ElementFamily.P,
        basix.CellType.triangle,
        cmap.degree,
        basix.LagrangeVariant(cmap.variant),
    )
    X = V.element.interpolation_points  # reference nodes of one block
    dphi = geom.tabulate(1, X)[1:, :, :, 0]  # (2, npts, ngeom)
    xg = msh.geometry.x[msh.geometry.dofmaps[0][cells], :2]  # (m, ngeom, 2)
    pts = closure[local]  # (m, k) local node indices of each facet's closure
    dphi_f = dphi[:, pts, :]  # (2, m, k, ngeom)
    jac = np.einsum("mad,rmka->mkdr", xg, dphi_f)  # (m, k, 2 (x, y), 2 (X, Y))
    n_ref = basix.cell.facet_outward_normals(basix.CellType.triangle)[local]  # (m, 2)
    # J^{-T} n_ref = cof(J) n_ref / det J; the cofactor matrix avoids the division.
    a, b, c, d = jac[..., 0, 0], jac[..., 0, 1], jac[..., 1, 0], jac[..., 1, 1]
    det = a * d - b * c
    nx = (d * n_ref[:, None, 0] - c * n_ref[:, None, 1]) / det
    ny = (-b * n_ref[:, None, 0] + a * n_ref[:, None, 1]) / det
    n = np.stack([nx, ny], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    blocks = np.asarray(V.dofmap.list[cells][np.arange(len(cells))[:, None], pts], np.int32)
    return blocks, n


class SlipConstraint:
    """Impose ``u . T = g`` or ``u . N = g`` at the boundary nodes of a curved boundary.

    Parameters
    ----------
    V
        The constrained vector field's space: a blocked Lagrange space with two components,
        or such a subspace of a mixed space (``W.sub(0)``).
    curved
        The curved mesh ``V`` lives on.
    tag
        Facet tag of the constrained boundary (default the immersed boundary).
    component
        ``"tangential"`` (slip: ``u . T = g``) or ``"normal"`` (``u . N = g``).
    value
        ``g``: a number, or a callable ``(n, 2) points -> (n,)`` evaluated at the points of
        :attr:`ConstrainedNodes.x`.
    tangent
        ``"true"``: frame of Gamma at the closest point of each node. ``"discrete"``: frame of
        the mesh facets at the node; where two facets' frames differ both conditions are
        imposed (see the module docstring).
    parallel_tol
        ``"discrete"`` only: two facet frames at a node count as different when the sine of
        the angle between them exceeds this (rounding gives ~1e-15; the corners of a P2
        boundary of curvature ``kappa`` have angles of order ``(kappa h)^2``).

    Notes
    -----
    The boundary may move: after the geometry (or the boundary object) changes, call
    :meth:`update`; forms compiled once are simply re-assembled. Every method is collective.
    """

    def __init__(
        self,
        V: fem.FunctionSpace,
        curved: CurvedMesh,
        tag: int = IMMERSED,
        component: str = "tangential",
        value: Value = 0.0,
        tangent: str = "true",
        *,
        parallel_tol: float = 1e-10,
    ) -> None:
        if component not in ("tangential", "normal"):
            raise ValueError(f"component must be 'tangential' or 'normal', got {component!r}")
        if tangent not in ("true", "discrete"):
            raise ValueError(f"tangent must be 'true' or 'discrete', got {tangent!r}")
        if V.mesh is not curved.mesh:
            raise ValueError("V must be a function space on curved.mesh")
        if tuple(V.value_shape) != (2,):
            raise ValueError(f"V must hold 2-vectors, got value shape {tuple(V.value_shape)}")
        self.V = V
        self.curved = curved
        self.tag = int(tag)
        self.component = component
        self.value = value
        self.tangent = tangent
        self.parallel_tol = float(parallel_tol)
        if V.component():  # a subspace of a mixed space
            Vc, cmap = V.collapse()
            cmap = np.asarray(cmap[0] if isinstance(cmap, list | tuple) else cmap, np.int32)
        else:
            Vc = V
            nb = V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts
            cmap = np.arange(2 * nb, dtype=np.int32)
        if Vc.dofmap.index_map_bs != 2:
            raise ValueError("V must be a blocked (vector) Lagrange space with block size 2")
        self._Vc = Vc
        self._pairs = cmap.reshape(-1, 2)  # parent-space dofs of (x, y) at each node
        self._prefix = f"dolfinx_universal_slip_{next(_counter)}_"
        self.rotation: PETSc.Mat | None = None
        self.nodes: ConstrainedNodes
        self.update()

    # ------------------------------------------------------------------ frames and R
    @property
    def comm(self) -> MPI.Comm:
        """Communicator of the mesh."""
        return self.curved.mesh.comm

    def update(self, curved: CurvedMesh | None = None) -> None:
        """Recompute the frames and the rotation after the geometry or boundary changed.

        Parameters
        ----------
        curved
            A new :class:`~dolfinx_universal.curved.maps.CurvedMesh` on the same DOLFINx mesh
            (e.g. with a moved boundary object); default: re-read ``self.curved``.
        """
        if curved is not None:
            if curved.mesh is not self.V.mesh:
                raise ValueError("update() needs a curved mesh on the same DOLFINx mesh as V")
            self.curved = curved
        if self.tangent == "true":
            self.nodes = self._true_nodes()
        else:
            self.nodes = self._discrete_nodes()
        if self.rotation is not None:
            self.rotation.destroy()
        self.rotation = self._rotation_matrix()

    def _values(self, x: Float) -> Float:
        """The prescribed values at the points ``x`` (collective: the user's ``value`` runs
        on each rank's own points, and a failure there raises on every rank)."""

        def values() -> Float:
            g = self.value(x) if callable(self.value) else np.full(len(x), float(self.value))
            return np.broadcast_to(np.asarray(g, dtype=np.float64), (len(x),)).copy()

        return collective_call(self.comm, "the constraint's value", values, error=RuntimeError)

    def _owned(self, blocks: npt.NDArray[np.int32]) -> npt.NDArray[np.bool_]:
        return blocks < self._Vc.dofmap.index_map.size_local

    def _true_nodes(self) -> ConstrainedNodes:
        blocks, y, n, t = boundary_dof_data(self._Vc, self.curved, self.tag)
        keep = self._owned(blocks)
        blocks, y, n, t = blocks[keep], y[keep], n[keep], t[keep]
        m = len(blocks)
        return ConstrainedNodes(
            blocks=blocks.astype(np.int32),
            dofs=self._pairs[blocks],
            x=y,
            normal=n,
            tangent=t,
            value=self._values(y),
            double=np.zeros(m, dtype=bool),
            u0=np.zeros((m, 2)),
        )

    def _discrete_nodes(self) -> ConstrainedNodes:
        Vc = self._Vc
        facets = self.curved.facet_tags.find(self.tag)  # owned facets: each counted once
        blocks, normals = facet_frames(Vc, facets)
        c = normals if self.component == "normal" else rot90(normals.reshape(-1, 2))
        c = c.reshape(-1, 2)
        # Per node: sum of c c^T (4), sum of c (2), count (1), gathered on the owner.
        data = np.column_stack(
            [c[:, 0] * c[:, 0], c[:, 0] * c[:, 1], c[:, 1] * c[:, 1], c, np.ones(len(c))]
        )
        im = Vc.dofmap.index_map
        acc = la.vector(im, 6, dtype=np.float64)
        acc.array[:] = 0.0
        np.add.at(acc.array.reshape(-1, 6), blocks.ravel(), data)
        acc.scatter_reverse(la.InsertMode.add)
        acc.scatter_forward()
        sums = acc.array.reshape(-1, 6)[: im.size_local]
        nodes = np.flatnonzero(sums[:, 5] > 0).astype(np.int32)
        s = sums[nodes]
        M = np.stack([s[:, 0], s[:, 1], s[:, 1], s[:, 2]], axis=1).reshape(-1, 2, 2)
        S = s[:, 3:5]
        # det(sum c_i c_i^T) = sin^2 of the angle between two unit vectors (count 2).
        det = np.linalg.det(M)
        double = (s[:, 5] > 1.5) & (det > self.parallel_tol**2)
        x = Vc.tabulate_dof_coordinates()[nodes, :2]
        g = self._values(x)
        cvec = S / np.linalg.norm(S, axis=1, keepdims=True)
        if self.component == "normal":
            normal, tangent = cvec, rot90(cvec)
        else:
            normal, tangent = -rot90(cvec), cvec
        # Both conditions c_i . u = g hold iff (sum c_i c_i^T) u = g sum c_i (M regular).
        u0 = np.zeros((len(nodes), 2))
        if double.any():
            u0[double] = np.linalg.solve(M[double], (g[double, None] * S[double])[..., None])[
                ..., 0
            ]
        return ConstrainedNodes(
            blocks=nodes,
            dofs=self._pairs[nodes],
            x=x,
            normal=normal,
            tangent=tangent,
            value=g,
            double=double,
            u0=u0,
        )

    def _global(self, local: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """Global (PETSc) indices of owned local dofs of the parent space."""
        im, bs = self.V.dofmap.index_map, self.V.dofmap.index_map_bs
        return np.asarray(local, dtype=np.int64) + im.local_range[0] * bs

    def _rotation_matrix(self) -> PETSc.Mat:
        """``R``: identity except ``[[N_x, T_x], [N_y, T_y]]`` on the (x, y) dofs of single
        nodes (owned rows, global columns; both dofs of a node are owned by the same rank)."""
        im, bs = self.V.dofmap.index_map, self.V.dofmap.index_map_bs
        n = im.size_local * bs
        nd = self.nodes
        single = ~nd.double
        i, j = nd.dofs[single, 0], nd.dofs[single, 1]
        N, T = nd.normal[single], nd.tangent[single]
        rotated = np.zeros(n, dtype=bool)
        rotated[i] = rotated[j] = True
        plain = np.flatnonzero(~rotated)
        rows = np.concatenate([plain, i, i, j, j])
        cols = np.concatenate([plain, i, j, i, j])
        vals = np.concatenate([np.ones(len(plain)), N[:, 0], T[:, 0], N[:, 1], T[:, 1]])
        order = np.lexsort((self._global(cols), rows))
        rows, cols, vals = rows[order], cols[order], vals[order]
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n))])
        R = PETSc.Mat().createAIJ(
            ((n, PETSc.DETERMINE), (n, PETSc.DETERMINE)),
            csr=(
                indptr.astype(PETSc.IntType),
                self._global(cols).astype(PETSc.IntType),
                vals.astype(PETSc.ScalarType),
            ),
            comm=self.comm,  # type: ignore[arg-type]  # petsc4py accepts an mpi4py Comm
        )
        R.assemble()
        return R

    # ------------------------------------------------------------------ assembly and solve
    def _dirichlet(self, bcs: Sequence[fem.DirichletBC]) -> tuple[npt.NDArray[np.int64], Float]:
        """Global rows and values (in rotated unknowns) of every strongly imposed condition."""
        nd = self.nodes
        single, double = ~nd.double, nd.double
        col = 1 if self.component == "tangential" else 0  # y = (y_N, y_T) on (x, y) dofs
        rows = [nd.dofs[single, col], nd.dofs[double, 0], nd.dofs[double, 1]]
        vals = [nd.value[single], nd.u0[double, 0], nd.u0[double, 1]]
        im, bs = self.V.dofmap.index_map, self.V.dofmap.index_map_bs
        n_owned = im.size_local * bs
        if bcs:
            x_bc = np.zeros((im.size_local + im.num_ghosts) * bs)
            marked = np.zeros(len(x_bc), dtype=bool)
            for bc in bcs:
                bc.set(x_bc)
                dofs, _ = bc.dof_indices()
                marked[dofs] = True
            marked = marked[:n_owned]
            clash = marked[nd.dofs.ravel()]
            bad = self.comm.allreduce(int(clash.sum()))
            if bad:
                raise ValueError(
                    f"{bad} Dirichlet dofs coincide with constrained nodes: a node cannot carry "
                    "both an ordinary Dirichlet condition and a component constraint"
                )
            bc_dofs = np.flatnonzero(marked)
            rows.append(bc_dofs)
            vals.append(x_bc[bc_dofs])
        r = np.concatenate(rows)
        return self._global(r), np.concatenate(vals)

    def assemble_system(
        self,
        a: fem.Form | ufl.Form,
        L: fem.Form | ufl.Form,
        bcs: Iterable[fem.DirichletBC] = (),
    ) -> tuple[PETSc.Mat, PETSc.Vec]:
        """Assemble ``R^T A R`` and ``R^T b`` with every strong condition imposed.

        The constrained rotated components and the dofs of ``bcs`` are removed symmetrically
        (rows and columns zeroed, 1 on the diagonal, the right-hand side lifted), so a
        symmetric ``a`` gives a symmetric matrix.

        Parameters
        ----------
        a, L
            Bilinear and linear forms on the parent space of ``V`` (compiled or UFL).
        bcs
            Ordinary Dirichlet conditions on dofs that are not constrained here.

        Returns
        -------
        The matrix and right-hand side in the rotated unknowns ``y`` (``u = R y``); the
        caller destroys them.
        """
        a = a if isinstance(a, fem.Form) else fem.form(a)
        L = L if isinstance(L, fem.Form) else fem.form(L)
        bcs = list(bcs)
        A = fem_petsc.assemble_matrix(a)
        A.assemble()
        b = fem_petsc.assemble_vector(L)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        R = self.rotation
        assert R is not None  # set by update() in __init__
        Ar = A.PtAP(R)
        A.destroy()
        br = b.duplicate()
        R.multTranspose(b, br)
        b.destroy()
        rows, vals = self._dirichlet(bcs)
        x = br.duplicate()
        x.zeroEntries()
        x.setValues(rows.astype(PETSc.IntType), vals)
        x.assemble()
        Ar.zeroRowsColumns(rows.astype(PETSc.IntType), 1.0, x, br)
        x.destroy()
        return Ar, br

    def solve(
        self,
        a: fem.Form | ufl.Form,
        L: fem.Form | ufl.Form,
        bcs: Iterable[fem.DirichletBC] = (),
        petsc_options: dict | None = None,
        u: fem.Function | None = None,
    ) -> fem.Function:
        """Assemble, rotate, constrain, solve (MUMPS LU by default) and rotate back.

        Parameters
        ----------
        a, L
            Bilinear and linear forms on the parent space of ``V``.
        bcs
            Ordinary Dirichlet conditions (on dofs that are not constrained here).
        petsc_options
            KSP/PC options (default :data:`DEFAULT_PETSC_OPTIONS`).
        u
            Function on the parent space to write the solution into. Default: a new one on
            the trial space of ``a`` (required when ``a`` is compiled and ``V`` a subspace).

        Returns
        -------
        The solution on the parent space (ghosts updated).
        """
        if u is None:
            if isinstance(a, fem.Form):
                if self.V.component():
                    raise ValueError("pass `u` (or UFL forms) when V is a subspace")
                u = fem.Function(self.V)
            else:
                u = fem.Function(a.arguments()[1].ufl_function_space())
        A, b = self.assemble_system(a, L, bcs)
        options = DEFAULT_PETSC_OPTIONS if petsc_options is None else petsc_options
        opts = PETSc.Options()
        for key, val in options.items():
            opts[f"{self._prefix}{key}"] = val  # type: ignore[index]  # stubs lack __setitem__
        ksp = PETSc.KSP().create(self.comm)  # type: ignore[arg-type]  # accepts an mpi4py Comm
        ksp.setOperators(A)
        ksp.setOptionsPrefix(self._prefix)
        ksp.setFromOptions()
        for key in options:
            del opts[f"{self._prefix}{key}"]  # type: ignore[attr-defined]  # stubs lack __delitem__
        y = b.duplicate()
        ksp.solve(b, y)
        reason = ksp.getConvergedReason()
        assert self.rotation is not None  # set by update() in __init__
        self.rotation.mult(y, u.x.petsc_vec)
        u.x.scatter_forward()
        for obj in (ksp, A, b, y):
            obj.destroy()
        if reason < 0:  # type: ignore[operator]  # stubs type the int reason as a class
            raise RuntimeError(f"linear solve failed (KSP converged reason {reason})")
        return u

    def residual(self, u: fem.Function) -> float:
        """Largest violation of the constraint over all constrained nodes (collective).

        ``max |u . c - g|`` at single nodes (``c`` the frame's tangent or normal) and
        ``max |u - u0|`` at double nodes.
        """
        nd = self.nodes
        uv = u.x.array[nd.dofs]  # (n, 2)
        c = nd.tangent if self.component == "tangential" else nd.normal
        r1 = np.abs(np.sum(uv * c, axis=1) - nd.value)[~nd.double]
        r2 = np.abs(uv - nd.u0)[nd.double].ravel()
        local = float(max(r1.max(initial=0.0), r2.max(initial=0.0)))
        return self.comm.allreduce(local, op=MPI.MAX)

    @property
    def num_constrained(self) -> tuple[int, int]:
        """Global numbers of single and double nodes (collective)."""
        d = self.nodes.double
        return (
            self.comm.allreduce(int((~d).sum())),
            self.comm.allreduce(int(d.sum())),
        )

    def __del__(self) -> None:
        rotation = getattr(self, "rotation", None)  # unset if __init__ failed early
        if rotation is not None:
            rotation.destroy()
