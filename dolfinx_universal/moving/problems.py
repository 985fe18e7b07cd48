"""Solving on a :class:`~dolfinx_universal.moving.domain.MovingDomain`: one matrix for every step.

The background mesh of a moving domain keeps its topology, so its dofmaps, the sparsity
pattern of every matrix and every compiled form serve all the steps; only the geometry, the
cell indicator ``md.active`` and the boundary conditions change. Four pieces:

* :func:`reassemble`: assemble a bilinear and a linear form, with boundary conditions,
  into an existing PETSc matrix and vector;
* :class:`ActiveForm`: a form compiled once whose cell integrals are assembled over the
  current step's active cells only (its integrands carry the factor ``md.active``, so the
  other cells add zeros);
* :class:`MovingLinearProblem`: :class:`dolfinx.fem.petsc.LinearProblem` (forms compiled
  once, one matrix, one vector, one KSP) with the inactive dofs fixed at every step, and
  assembly and solve callable (and timed) separately;
* :class:`MovingStokes`: Taylor–Hood Stokes flow around moving rigid bodies in a fixed
  container, with the force and the torque on the bodies (assembled over the active cells).

Why not plain ``LinearProblem.solve``: it does reassemble into the matrix it created (the
sparsity stays valid on a moving domain) and its ``bcs`` may be replaced between solves,
but it fuses assembly and factorisation, so matrix options that the assembly resets
(``MAT_SYMMETRIC`` for a Cholesky factorisation) cannot be set in between, and neither
stage can be timed on its own. :class:`MovingLinearProblem` keeps its constructor and its
objects and splits :meth:`~MovingLinearProblem.solve` in two.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from functools import cached_property, partial
from typing import TYPE_CHECKING, Any

from mpi4py import MPI
from petsc4py import PETSc

import basix.ufl
import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem
from dolfinx import mesh as dmesh
from dolfinx.fem.petsc import LinearProblem
from ufl.algorithms import extract_coefficients

from dolfinx_universal.boundaries.domains import Domain
from dolfinx_universal.core.collective import collective_call
from dolfinx_universal.moving import rigid_tet, rigid_tri

if TYPE_CHECKING:
    from dolfinx_universal.moving.domain import MovingDomain

__all__ = ["DIRECT", "ITERATIVE", "ActiveForm", "MovingLinearProblem", "MovingStokes", "reassemble"]

_RIGID = {2: rigid_tri, 3: rigid_tet}
"""The rigid rotations and torques per geometric dimension."""


def reassemble(A, b, a: fem.Form, L: fem.Form, bcs: Sequence[fem.DirichletBC]) -> None:
    """Assemble ``a`` and ``L`` with ``bcs`` into the existing PETSc matrix and vector.

    On a :class:`~dolfinx_universal.moving.domain.MovingDomain` the sparsity of ``A`` (from
    :func:`dolfinx.fem.petsc.create_matrix` before the first step) stays valid for every
    step; only the values and the boundary conditions change.
    """
    from dolfinx.fem.petsc import apply_lifting, assemble_matrix, assemble_vector, set_bc

    bcs = list(bcs)
    A.zeroEntries()
    assemble_matrix(A, a, bcs=bcs)
    A.assemble()
    with b.localForm() as local:
        local.set(0.0)
    assemble_vector(b, L)
    apply_lifting(b, [a], [bcs])
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    set_bc(b, bcs)


RESTRICT_SHARE = 0.5
"""Largest share of active unknowns at which ``MovingLinearProblem(restrict_to_active=None)``
solves the submatrix of the active unknowns. Measured with MUMPS on Stokes (Taylor–Hood,
q = 2): curved tetrahedra, 21 % active of 7.4e4 unknowns, 0.85 s against 8.0 s for the
whole matrix; triangles, 26 % active of 4.2e5, 1.08 s against 3.2 s; but triangles at
68 % active, 3.7 s against 3.3 s: the whole matrix keeps its sparsity from step to step,
so its symbolic factorisation is reused, the submatrix's is redone at every solve."""

ACTIVE_ID = 2**30 - 17
"""Subdomain id that :class:`ActiveForm` gives a form's cell integrals (an unlikely one)."""


class ActiveForm:
    """A form whose cell integrals are assembled over the active cells only, compiled once.

    A cell integral whose integrand has the factor ``md.active`` vanishes on the inactive
    cells, so it may skip them: the element tensors of the active cells, added in the same
    order, are those of the whole background, less exact zeros. The UFL form is compiled
    once with its cell integrals given the id :data:`ACTIVE_ID`
    (:func:`dolfinx.fem.compile_form`); :meth:`step` makes the DOLFINx form of the current
    active cells (:func:`dolfinx.fem.create_form`, no compilation), :attr:`full` the one of
    every owned cell, whose sparsity pattern holds every step's.

    Parameters
    ----------
    md
        The moving domain.
    form
        A UFL form whose integrals all have the default subdomain (``dx``, ``ds``, ``dS``
        without an id or data) and whose cell integrands all vanish where ``md.active`` does
        (a factor ``md.active``; an integrand without it is an error).
    on_gamma
        Its interior-facet integrands vanish off Gamma_h too (those of
        :meth:`~dolfinx_universal.moving.domain.MovingDomain.immersed_integral`): they run on the
        facets of Gamma_h only. Otherwise interior and exterior facet integrals run on
        every facet.
    """

    def __init__(self, md: MovingDomain, form: ufl.Form, *, on_gamma: bool = False):
        restricted = ("cell", "interior_facet") if on_gamma else ("cell",)
        integrals = []
        for itg in form.integrals():
            if itg.subdomain_id() != "everywhere" or itg.subdomain_data() is not None:
                raise ValueError(
                    "an ActiveForm's integrals must have no subdomain id or data, got "
                    f"{itg.integral_type()} integral {itg.subdomain_id()!r}"
                )
            if itg.integral_type() in restricted:
                if md.active not in extract_coefficients(itg.integrand()):
                    raise ValueError(
                        f"an ActiveForm's {itg.integral_type()} integrand must carry the "
                        "indicator md.active (it is assembled where md.active is 1 only)"
                    )
                itg = itg.reconstruct(subdomain_id=ACTIVE_ID)
            integrals.append(itg)
        self.md = md
        self.on_gamma = on_gamma
        self.ufl_form = ufl.Form(integrals)
        self.compiled = fem.compile_form(md.comm, self.ufl_form)
        self._spaces = [arg.ufl_function_space() for arg in form.arguments()]
        self._coefficients = {c: c for c in form.coefficients()}
        self._constants = {c: c for c in ufl.algorithms.analysis.extract_constants(form)}
        topology = md.mesh.topology
        tdim = topology.dim
        self._num_owned = topology.index_map(tdim).size_local
        if on_gamma:
            topology.create_connectivity(tdim - 1, tdim)
            topology.create_connectivity(tdim, tdim - 1)

    @cached_property
    def full(self) -> fem.Form:
        """The form over every owned cell (and every interior facet, with ``on_gamma``)."""
        topology = self.md.mesh.topology
        facets = np.arange(topology.index_map(topology.dim - 1).size_local, dtype=np.int32)
        return self._create(np.arange(self._num_owned, dtype=np.int32), facets)

    def _create(self, cells: npt.NDArray[np.int32], facets: npt.NDArray[np.int32]) -> fem.Form:
        domains = {fem.IntegralType.cell: [(ACTIVE_ID, cells)]}
        if self.on_gamma:
            pairs = fem.compute_integration_domains(
                fem.IntegralType.interior_facet, self.md.mesh.topology, facets
            )
            domains[fem.IntegralType.interior_facet] = [(ACTIVE_ID, np.asarray(pairs))]
        return fem.create_form(
            self.compiled,
            self._spaces,
            self.md.mesh,
            domains,
            self._coefficients,
            self._constants,
        )

    def step(self) -> fem.Form:
        """The form over the owned active cells of the current step (and the owned facets of
        Gamma_h, with ``on_gamma``)."""
        cells = self.md.active_cells
        owned = cells[cells < self._num_owned]
        return self._create(
            np.ascontiguousarray(owned, dtype=np.int32),
            np.ascontiguousarray(self.md.immersed_facets, dtype=np.int32),
        )

    def create_matrix(self) -> PETSc.Mat:
        """A matrix for every step's :meth:`step` form (bilinear forms): the sparsity of the
        whole background, every entry stored (zero). Collective."""
        from dolfinx.fem.petsc import create_matrix

        A = create_matrix(self.full)
        _fill_pattern(A, self)
        return A


def _fill_pattern(A, form: ActiveForm) -> None:
    """Set every entry of the sparsity pattern of ``A`` (the whole background's) to zero.

    PETSc drops the preallocated entries that the first assembly leaves unset, so that the
    active cells of a later step would have no place in ``A``; one assembly over every cell
    of a cheap zero form (one quadrature point) keeps them all.
    """
    from dolfinx.fem.petsc import assemble_matrix

    V0, V1 = (arg.ufl_function_space() for arg in form.ufl_form.arguments())
    u, v = ufl.TrialFunction(V1), ufl.TestFunction(V0)
    facets = any(itg.integral_type() == "interior_facet" for itg in form.ufl_form.integrals())
    if u.ufl_shape == v.ufl_shape and not facets:
        zero = fem.Constant(form.md.mesh, np.zeros((), dtype=PETSc.ScalarType))
        dx = ufl.dx(domain=form.md.mesh, metadata={"quadrature_degree": 0})
        assemble_matrix(A, fem.form(zero * ufl.inner(u, v) * dx))
    else:  # the form itself, on every cell (and facet: their pairs of cells couple)
        assemble_matrix(A, form.full)
    A.assemble()


def _component(fn: Callable[[str], Any], i: int, side: str) -> Any:
    """Component ``i`` of ``fn(side)`` (a UFL vector)."""
    return fn(side)[i]


class MovingLinearProblem(LinearProblem):
    """A linear problem on a moving domain, assembled into the same matrix at every step.

    The forms are written with the indicator (``md.active * ... * dx``); at every
    :meth:`assemble` the dofs of the unknown's space that belong to no active cell are fixed
    at zero (before the other conditions, which win where they overlap), so that the system
    on the whole background is nonsingular.

    Parameters
    ----------
    md
        The moving domain whose :attr:`~dolfinx_universal.moving.domain.MovingDomain.mesh` the
        forms live on.
    a, L
        Bilinear and linear forms (UFL or compiled; one block).
    petsc_options_prefix, petsc_options, u
        As in :class:`dolfinx.fem.petsc.LinearProblem` (``u``: the solution function).
    P
        A bilinear form whose matrix preconditions the KSP (as in
        :class:`~dolfinx.fem.petsc.LinearProblem`), assembled with the same conditions at
        every :meth:`assemble` (over the active cells with ``active_only``) into
        :attr:`P_mat`, and restricted with the system where it is; while
        :attr:`precondition` is False it is neither assembled nor used (a direct solver
        factorises the preconditioning matrix).
    fields
        Named fields for ``pc_type: fieldsplit``: ``(name, unknowns)`` pairs, ``unknowns``
        the process-local indices of owned unknowns (``block * bs + component``) of each
        field. They are given to the PC in the numbering of the matrix solved (the whole
        one or the submatrix of the active unknowns). Other PC types ignore them.
    symmetric
        Mark the matrix symmetric after each assembly (for ``pc_type: cholesky``).
    active_only
        Assemble the cell integrals over the active cells only (:class:`ActiveForm`): exact
        when every cell integrand has the factor ``md.active`` (the others vanish there),
        and cheaper by the inactive cells' share of the background. Needs UFL forms whose
        integrals have no subdomain id or data.
    restrict_to_active
        Let the KSP solve the submatrix of the unknowns of the active cells only (the same
        solution: the others are fixed, decoupled), or the whole matrix (False), or decide
        at each solve (None): the submatrix where the active unknowns are at most
        :data:`RESTRICT_SHARE` of all. The KSP then sees a new operator at each step: a
        null space or options attached to :attr:`A` do not reach it; and it is a new
        :attr:`solver` made from ``petsc_options`` (settings made on the old one are not
        kept).
    """

    def __init__(
        self,
        md: MovingDomain,
        a: ufl.Form | fem.Form,
        L: ufl.Form | fem.Form,
        *,
        petsc_options_prefix: str,
        petsc_options: dict | None = None,
        u: fem.Function | None = None,
        P: ufl.Form | fem.Form | None = None,
        fields: Sequence[tuple[str, npt.ArrayLike]] = (),
        symmetric: bool = False,
        active_only: bool = False,
        restrict_to_active: bool | None = False,
    ):
        if any(isinstance(f, Sequence) for f in (a, L, P)):
            raise TypeError("MovingLinearProblem takes one bilinear and one linear form")
        if u is None and isinstance(L, fem.Form):  # LinearProblem reads it from a UFL form
            raise TypeError("give the solution function u with compiled forms")
        self._active: list[ActiveForm] | None = None
        if active_only:
            forms = [a, L] if P is None else [a, L, P]
            if not all(isinstance(f, ufl.Form) for f in forms):
                raise TypeError("active_only=True needs UFL forms (a, L and P)")
            if u is None:
                u = fem.Function(L.arguments()[0].ufl_function_space())
            self._active = [ActiveForm(md, f) for f in forms]
            a, L = self._active[0].full, self._active[1].full
            if P is not None:
                P = self._active[2].full
        super().__init__(
            a, L, P=P, petsc_options_prefix=petsc_options_prefix, petsc_options=petsc_options, u=u
        )
        # LinearProblem's tidy-up of the global options leaves them (the pushed prefix is
        # not applied to the deletions): remove them here, and give them at every solve
        # instead (sub-solvers, such as a field split's, read theirs at the set-up).
        self._petsc_options = dict(petsc_options or {})
        options = PETSc.Options(petsc_options_prefix)
        for key in self._petsc_options:
            options.delValue(key)
        self.md = md
        self.symmetric = symmetric
        self.restrict_to_active = restrict_to_active
        self._restricted: list[PETSc.Mat] = []
        self._inactive = np.empty(0, dtype=np.int32)
        self._zero = fem.Function(self.u.function_space)
        if self._active is not None:
            _fill_pattern(self.A, self._active[0])
            if self.P_mat is not None:
                _fill_pattern(self.P_mat, self._active[2])
        V = self.u.function_space
        owned = V.dofmap.index_map.size_local * V.dofmap.index_map_bs
        self._fields = [(str(n), np.unique(np.asarray(f, dtype=np.int64))) for n, f in fields]
        bad = [name for name, idx in self._fields if len(idx) and (idx[0] < 0 or idx[-1] >= owned)]
        if md.comm.allreduce(len(bad) > 0, op=MPI.LOR):  # on every rank
            raise ValueError(
                f"fields {bad or 'of another rank'}: unknowns must be process-local indices of "
                f"owned unknowns, in [0, {owned}) on this rank"
            )
        self._fields_given = False  # whether the KSP's PC holds the fields
        self.precondition = self.P_mat is not None
        """Whether :meth:`assemble` assembles ``P`` and the KSP preconditions with it (else
        with ``A``, as a direct solver needs). Set it with :meth:`set_petsc_options`."""

    def set_petsc_options(self, petsc_options: dict, *, precondition: bool = False) -> None:
        """Solve with other KSP options from now on, such as another solver when the active
        set has grown (collective): a new :attr:`solver` with these options, which replace
        the ones given before. ``precondition``: precondition with ``P`` (a Krylov method) or
        not (a direct solver: it factorises the preconditioning matrix)."""
        if self.P_mat is None and precondition:
            raise ValueError("precondition=True needs the problem's preconditioner form P")
        self.precondition = precondition
        self._petsc_options = dict(petsc_options)
        self._new_solver()

    def _new_solver(self) -> None:
        """Replace :attr:`solver` by a new KSP with the problem's options (collective).

        Not ``KSP.reset``: a reset field split keeps its record that its sub-solvers have
        read their options, so the sub-solvers of new fields would keep PETSc's defaults
        (seen: ILU instead of the LU asked for, 53 iterations instead of 1)."""
        old: PETSc.KSP = self.solver
        ksp = PETSc.KSP().create(old.getComm())
        ksp.setOptionsPrefix(old.getOptionsPrefix())
        with self._options():
            ksp.setFromOptions()
        old.destroy()
        self._solver = ksp
        self._fields_given = False
        for obj in self._restricted:  # (the old KSP held them)
            obj.destroy()
        self._restricted = []

    @contextmanager
    def _options(self) -> Iterator[None]:
        """The problem's options in PETSc's database under its prefix, for the block."""
        options = PETSc.Options(self.solver.getOptionsPrefix())
        for key, value in self._petsc_options.items():
            options.setValue(key, value)
        try:
            yield
        finally:
            for key in self._petsc_options:
                options.delValue(key)

    def _give_fields(self, position: Callable[[npt.NDArray[np.int64]], npt.NDArray[np.int64]]):
        """Give the fields to the PC, each unknown at ``position(unknowns)`` in the matrix
        solved (-1: not in it)."""
        comm = self.A.getComm()
        splits = []
        for name, unknowns in self._fields:
            at = position(unknowns)
            index: Any = at[at >= 0].astype(PETSc.IntType)
            splits.append((name, PETSc.IS().createGeneral(index, comm)))
        self.solver.getPC().setFieldSplitIS(*splits)
        for _, index_set in splits:
            index_set.destroy()
        self._fields_given = True

    def __del__(self):
        """Leave the PETSc objects to petsc4py's collective garbage collection.

        ``LinearProblem.__del__`` destroys them at once, a collective call; problems held in
        reference cycles are collected at different times on different ranks, and the
        ranks then deadlock (seen at the exit of the demos under mpirun).
        """

    def assemble(self, bcs: Sequence[fem.DirichletBC] = ()) -> None:
        """Fix the inactive dofs, then assemble with ``bcs`` into ``A`` and ``b`` (collective).

        Sets :attr:`bcs` to the conditions used: the inactive dofs first, then ``bcs``.
        """
        self._inactive = self.md.inactive_dofs(self.u.function_space)
        inactive = fem.dirichletbc(self._zero, self._inactive)
        self.bcs = [inactive, *bcs]
        if self._active is None:
            a, L, P = self.a, self.L, self.preconditioner
        else:
            a, L = (form.step() for form in self._active[:2])
            P = self._active[2].step() if self.precondition else None
        reassemble(self.A, self.b, a, L, self.bcs)
        if self.symmetric:
            self.A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
        if self.precondition:
            from dolfinx.fem.petsc import assemble_matrix

            self.P_mat.zeroEntries()
            assemble_matrix(self.P_mat, P, bcs=self.bcs)
            self.P_mat.assemble()

    def solve_assembled(self) -> fem.Function:
        """Solve the system assembled by :meth:`assemble` into :attr:`u` (collective).

        With ``restrict_to_active``, the KSP solves the submatrix of the unknowns of the
        active cells; every other unknown is fixed by :meth:`assemble` (an identity row, its
        column zero), so it takes its value from the right-hand side.

        Raises
        ------
        RuntimeError
            When the KSP does not converge.
        """
        u = self.u.x.petsc_vec
        V = self.u.function_space
        imap, bs = V.dofmap.index_map, V.dofmap.index_map_bs
        restrict = self.restrict_to_active
        if restrict is not False:  # the owned unknowns of the active cells
            keep = np.ones(imap.size_local, dtype=bool)
            keep[self._inactive[self._inactive < imap.size_local]] = False
        if restrict is None:  # where the active unknowns are at most half of them
            active = self.md.comm.allreduce(int(np.count_nonzero(keep)))
            restrict = active <= RESTRICT_SHARE * imap.size_global
        if not restrict:
            if self._restricted:  # the previous solve had the submatrix
                self._new_solver()
            self.solver.setOperators(self.A, self.P_mat if self.precondition else self.A)
            if self._fields and not self._fields_given:
                self._give_fields(lambda unknowns: unknowns + imap.local_range[0] * bs)
            with self._options():
                self.solver.solve(self.b, u)
        else:
            kept = np.flatnonzero(keep)
            blocks = (kept + imap.local_range[0]).astype(PETSc.IntType)
            rows = PETSc.IS().createBlock(bs, blocks, comm=self.A.getComm())
            A = self.A.createSubMatrix(rows, rows)
            if self.symmetric:
                A.setOption(PETSc.Mat.Option.SYMMETRIC, True)
            P = self.P_mat.createSubMatrix(rows, rows) if self.precondition else None
            sub = self.b.getSubVector(rows)
            rhs = sub.copy()
            self.b.restoreSubVector(rows, sub)
            x = rhs.duplicate()
            self._new_solver()  # the operator's size changes with the active set
            self.solver.setOperators(A, P)
            if self._fields:  # positions in the submatrix: the kept blocks in order
                comm: Any = self.md.comm
                first = comm.exscan(len(kept) * bs) or 0
                at = np.full(imap.size_local, -1, dtype=np.int64)
                at[kept] = first + bs * np.arange(len(kept))

                def position(unknowns: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
                    b, c = np.divmod(unknowns, bs)
                    return np.where(at[b] >= 0, at[b] + c, -1)

                self._give_fields(position)
            with self._options():
                self.solver.solve(rhs, x)
            self.b.copy(u)  # the fixed unknowns: their identity rows
            sub = u.getSubVector(rows)
            x.copy(sub)
            u.restoreSubVector(rows, sub)
            for obj in (rows, rhs, x):
                obj.destroy()
            self._restricted = [A] if P is None else [A, P]  # held by the KSP until the next
        self.u.x.scatter_forward()
        reason = self.solver.getConvergedReason()
        if reason <= 0:
            raise RuntimeError(f"the linear solver failed (KSP reason {reason})")
        return self.u

    def solve(self, bcs: Sequence[fem.DirichletBC] = ()) -> fem.Function:
        """:meth:`assemble` with ``bcs``, then :meth:`solve_assembled`."""
        self.assemble(bcs)
        return self.solve_assembled()


VelocityData = npt.ArrayLike | Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]]
"""A velocity: a constant vector ``(gdim,)``, or ``x (3, n) -> values (gdim, n)``."""

DIRECT = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
"""MUMPS LU: the default solver of :class:`MovingStokes`."""

ITERATIVE = {
    "ksp_type": "fgmres",
    "ksp_gmres_restart": 200,
    "ksp_rtol": 1e-10,
    "ksp_atol": 0.0,
    "ksp_max_it": 1000,
    "pc_type": "fieldsplit",
    "pc_fieldsplit_type": "schur",
    "pc_fieldsplit_schur_fact_type": "upper",
    "pc_fieldsplit_schur_precondition": "a11",
    "fieldsplit_u_ksp_type": "preonly",
    "fieldsplit_u_pc_type": "gamg",
    "fieldsplit_u_pc_gamg_threshold": 0.02,
    "fieldsplit_u_mg_levels_ksp_type": "chebyshev",
    "fieldsplit_u_mg_levels_pc_type": "jacobi",
    "fieldsplit_p_ksp_type": "preonly",
    "fieldsplit_p_pc_type": "jacobi",
}
"""Flexible GMRES (relative residual 1e-10) with the upper block-triangular factorisation of
the saddle point system, for :class:`MovingStokes` with ``preconditioner=True``: one
algebraic multigrid cycle (GAMG, Chebyshev-Jacobi smoothing) on the velocity block of the
preconditioner matrix, and the Jacobi iteration of its scaled pressure mass matrix for the
Schur complement. For systems beyond direct factorisation (3D, some 1e5 unknowns)."""


class MovingStokes:
    """Quasi-static Stokes flow around rigid bodies moving in a fixed container.

    Taylor–Hood :math:`P_2/P_1` on the degree-q mesh of ``md`` (triangles or tetrahedra),
    on the whole background with the indicator :math:`\\chi` = ``md.active``:

    .. math:: a((u, p), (v, q)) = \\int \\chi \\bigl(2\\mu\\, \\varepsilon(u) :
       \\varepsilon(v) - p \\operatorname{div} v - q \\operatorname{div} u\\bigr)\\, dx = 0.

    The container walls, with the velocity ``wall_velocity``, are the background's exterior
    facets (never moved, always in the fluid) or, where the domain of the step is a
    :class:`~dolfinx_universal.boundaries.domains.Domain` with a container, the part of Gamma_h
    nearer to the container than to every body. On the rest of Gamma_h (the bodies) the
    bodies' velocity is given at each :meth:`solve`; the dofs of no fluid cell are zero; the
    pressure is pinned to zero at ``pressure_point``, a background vertex that stays in the
    fluid (the forces do not depend on this constant). The spaces, the forms (also those of
    the forces), the matrix and the solver are built once; each :meth:`solve` locates the
    dofs on Gamma_h of the current step, reassembles and solves. The cell integrals are
    assembled over the active cells only (:class:`ActiveForm`): the same matrix as over the
    whole background, at the cost of the fluid's cells; and the solve takes the submatrix
    of the active unknowns where they are at most half of all
    (``MovingLinearProblem(restrict_to_active=None)``).

    Forces and torques on the bodies (about the origin; in 2D a scalar, positive
    counter-clockwise, in 3D a vector) come two ways; ``n`` is the fluid's outward normal,
    so the bodies' is ``-n``:

    * weak residual (reaction), :meth:`force` and :meth:`torque`:
      :math:`F \\cdot w = -a((u_h, p_h), (w, 0))` with ``w`` the :math:`P_2` field equal to
      the rigid motion (``e_i``, or ``e_k x x``) at the velocity nodes on the bodies and
      zero at every other node; by Green's formula this is
      :math:`-\\int_\\Gamma \\sigma n \\cdot w\\, ds`, and it superconverges (the error is a
      product of two energy-norm errors);
    * surface integrals on the curved Gamma_h, :meth:`surface_force` and
      :meth:`surface_torque`: traces of :math:`\\nabla u_h` and :math:`p_h`, one order
      less (the whole of Gamma_h: use them without an immersed container).

    Parameters
    ----------
    md
        The moving domain (updated by the caller before each :meth:`solve`).
    mu
        Viscosity.
    pressure_point
        Coordinates ``(gdim,)`` of the vertex where ``p = 0``.
    wall_velocity
        Velocity on the container walls (default 0).
    petsc_options, petsc_options_prefix
        Solver options (default MUMPS LU, :data:`DIRECT`; :data:`ITERATIVE` with
        ``preconditioner=True``); ``symmetric=True`` marks the
        matrix symmetric (for ``pc_type: cholesky``, MUMPS :math:`LDL^T`). The fields
        ``u`` and ``p`` are given for ``pc_type: fieldsplit``.
    preconditioner
        Assemble a preconditioner matrix at every step (over the active cells, with the
        same conditions), the vector Laplacian and the scaled pressure mass matrix,
        :math:`P = \\int \\chi (\\mu \\nabla u : \\nabla v - p q / \\mu)\\, dx`: the velocity
        block is equivalent to the symmetric gradient's on velocities that vanish on the
        walls (Korn), the pressure block spectrally equivalent to the Schur complement
        :math:`-B A^{-1} B^T`. For Krylov methods, such as :data:`ITERATIVE`.
    restrict_to_active
        As in :class:`MovingLinearProblem` (default: where the active unknowns are at most
        half). Krylov methods gain from the submatrix at any share (``True``): every
        product of the whole matrix also reads the fixed unknowns' rows.
    """

    def __init__(
        self,
        md: MovingDomain,
        mu: float,
        pressure_point: Sequence[float],
        *,
        wall_velocity: VelocityData | None = None,
        petsc_options: dict | None = None,
        petsc_options_prefix: str = "moving_stokes_",
        symmetric: bool = False,
        preconditioner: bool = False,
        restrict_to_active: bool | None = None,
    ):
        self.md, self.mu = md, mu
        msh = self.mesh = md.mesh
        d = self.gdim = msh.geometry.dim
        self._rigid = _RIGID[d]
        msh.topology.create_connectivity(msh.topology.dim - 1, msh.topology.dim)
        u_dofs, p_dofs = self._spaces()
        self.wh = fem.Function(self.W)
        """The solution ``(u_h, p_h)`` of the last :meth:`solve`."""
        self.problem = self._linear_problem(
            u_dofs,
            p_dofs,
            petsc_options=(ITERATIVE if preconditioner else DIRECT)
            if petsc_options is None
            else petsc_options,
            petsc_options_prefix=petsc_options_prefix,
            symmetric=symmetric,
            preconditioner=preconditioner,
            restrict_to_active=restrict_to_active,
        )
        self._fixed_conditions(wall_velocity, pressure_point)
        self.u_body = fem.Function(self.V, name="body_velocity")
        """The velocity on Gamma_h of the last :meth:`solve` (at every node; the walls'
        on an immersed container)."""
        # e_k x x at every node (2D only k = z; 3D k = x, y, z), at every step's geometry
        self._rotations = [fem.Function(self.V) for _ in range(self._rigid.ROTATIONS)]
        self._force_forms()
        self.body_dofs: list[npt.NDArray[np.int32]] = [np.empty(0, np.int32)] * 2
        """``[dofs of W, dofs of V]`` of the velocity on the bodies at the last solve."""

    def _spaces(self) -> tuple[npt.NDArray[np.int32], npt.NDArray[np.int32]]:
        """The Taylor–Hood space ``W`` and its collapsed velocity and pressure spaces ``V``,
        ``Q``; returns the dofs of ``W`` of each."""
        msh, d = self.mesh, self.gdim
        cell = msh.basix_cell()
        P2v = basix.ufl.element("Lagrange", cell, 2, shape=(d,))
        P1 = basix.ufl.element("Lagrange", cell, 1)
        W = self.W = fem.functionspace(msh, basix.ufl.mixed_element([P2v, P1]))
        self.V, u_dofs = W.sub(0).collapse()
        self.Q, p_dofs = W.sub(1).collapse()
        return np.asarray(u_dofs), np.asarray(p_dofs)

    def _linear_problem(
        self,
        u_dofs: npt.NDArray[np.int32],
        p_dofs: npt.NDArray[np.int32],
        *,
        preconditioner: bool,
        **options: Any,
    ) -> MovingLinearProblem:
        """The Stokes forms with the indicator, the preconditioner's if asked for, and the
        :class:`MovingLinearProblem` solving them into :attr:`wh` (``options``: its
        ``petsc_options``, ``petsc_options_prefix``, ``symmetric``,
        ``restrict_to_active``)."""
        msh, mu, W = self.mesh, self.mu, self.W
        (u, p), (v, q) = ufl.TrialFunctions(W), ufl.TestFunctions(W)
        chi = self.md.active
        a = (
            chi
            * (2 * mu * ufl.inner(self.eps(u), self.eps(v)) - p * ufl.div(v) - q * ufl.div(u))
            * ufl.dx
        )
        zero = fem.Constant(msh, np.zeros(self.gdim, dtype=PETSc.ScalarType))
        L = chi * ufl.inner(zero, v) * ufl.dx
        P = None
        if preconditioner:
            P = chi * (mu * ufl.inner(ufl.grad(u), ufl.grad(v)) - p * q / mu) * ufl.dx
        owned = W.dofmap.index_map.size_local  # (a mixed space: one index per unknown)
        fields = [(name, dofs[dofs < owned]) for name, dofs in (("u", u_dofs), ("p", p_dofs))]
        return MovingLinearProblem(
            self.md, a, L, u=self.wh, P=P, fields=fields, active_only=True, **options
        )

    def _fixed_conditions(
        self, wall_velocity: VelocityData | None, pressure_point: Sequence[float]
    ) -> None:
        """The conditions that do not change: the walls (the background's exterior facets)
        at ``wall_velocity`` and the pressure pinned to zero at ``pressure_point``."""
        msh, d, W, V, Q = self.mesh, self.gdim, self.W, self.V, self.Q
        walls = dmesh.exterior_facet_indices(msh.topology)
        self.u_wall = fem.Function(V, name="wall_velocity")
        self._set_velocity(self.u_wall, np.zeros(d) if wall_velocity is None else wall_velocity)
        wall_dofs = fem.locate_dofs_topological((W.sub(0), V), msh.topology.dim - 1, walls)
        self.bc_wall = fem.dirichletbc(self.u_wall, wall_dofs, W.sub(0))
        point = np.asarray(pressure_point, dtype=np.float64)
        if point.shape != (d,):
            raise ValueError(f"pressure_point must have {d} coordinates, got {pressure_point}")
        corner = fem.locate_dofs_geometrical(
            (W.sub(1), Q), lambda y: np.all(np.isclose(y[:d].T, point), axis=1)
        )
        owned = np.count_nonzero(corner[1] < Q.dofmap.index_map.size_local)
        if self.md.comm.allreduce(owned) != 1:
            raise ValueError(f"pressure_point {pressure_point} is not one vertex of the mesh")
        self.bc_pressure = fem.dirichletbc(fem.Function(Q), corner, W.sub(1))

    def _force_forms(self) -> None:
        """The forms of the forces and torques on the bodies: the weak residuals against
        the rigid test fields (their nodes on the bodies, set at each step) and the surface
        integrals on Gamma_h."""
        md, mu, d = self.md, self.mu, self.gdim
        chi = md.active
        # The rigid motions at the nodes on the bodies (zero elsewhere), for the reactions.
        self._tests = [fem.Function(self.V) for _ in range(d + len(self._rotations))]
        uh, ph = ufl.split(self.wh)
        self._reaction = [
            ActiveForm(
                md,
                -chi * (2 * mu * ufl.inner(self.eps(uh), self.eps(w)) - ph * ufl.div(w)) * ufl.dx,
            )
            for w in self._tests
        ]
        n, x = ufl.FacetNormal(self.mesh), ufl.SpatialCoordinate(self.mesh)

        def traction(side: str):
            """``sigma nu`` with ``nu = -n`` the bodies' outward normal."""
            return -ufl.dot(self.sigma(uh, ph)(side), n(side))

        self._surface = [
            ActiveForm(md, md.immersed_integral(partial(_component, traction, i)), on_gamma=True)
            for i in range(d)
        ]
        self._surface += [
            ActiveForm(md, md.immersed_integral(moment), on_gamma=True)
            for moment in self._rigid.moments(traction, x)
        ]

    def eps(self, w):
        """The strain rate ``sym(grad w)``."""
        return ufl.sym(ufl.grad(w))

    def sigma(self, w, r):
        """The Cauchy stress ``-r I + 2 mu eps(w)``."""
        return -r * ufl.Identity(self.gdim) + 2 * self.mu * self.eps(w)

    def _set_velocity(self, f: fem.Function, value: VelocityData) -> None:
        if callable(value):  # the user's function on each rank's own points: collective
            collective_call(self.md.comm, "the velocity", f.interpolate, value, error=RuntimeError)
        else:
            f.x.array.reshape(-1, self.gdim)[:] = np.asarray(value, dtype=np.float64)

    def _on_bodies(self, blocks: npt.NDArray[np.int32]) -> npt.NDArray[np.bool_]:
        """Which velocity nodes (blocks of V) on Gamma_h belong to a body: all, unless the
        current domain has a container, whose nodes are those nearer to it than to every
        body."""
        boundary = self.md.boundary
        if not isinstance(boundary, Domain) or boundary.container is None:
            return np.ones(len(blocks), dtype=bool)
        x = self.V.tabulate_dof_coordinates()[blocks, : self.gdim]
        is_body = np.array([body for _, body in boundary.components])
        # On every rank, with its own nodes (maybe none): a failing projection raises on all.
        nearest = collective_call(
            self.md.comm, "closest-point projection", boundary.nearest_component, x
        )
        return is_body[nearest]

    def boundary_conditions(
        self,
        boundary_velocity: VelocityData | None = None,
        angular_velocity: npt.ArrayLike = 0.0,
    ) -> list[fem.DirichletBC]:
        """The conditions of the current step, after the inactive dofs: the walls, the
        bodies' velocity ``boundary_velocity + angular_velocity x x`` on their part of
        Gamma_h (``angular_velocity``: a scalar about ``e_z`` in 2D, a vector in 3D), the
        wall velocity on an immersed container, the pressure pin. Sets the rigid test
        fields of :meth:`force` and :meth:`torque`."""
        W, V, d = self.W, self.V, self.gdim
        on_gamma = self.md.immersed_dofs((W.sub(0), V))
        assert isinstance(on_gamma, list)  # a (sub-space, collapsed) pair gives two arrays
        bs = V.dofmap.index_map_bs
        body = self._on_bodies(on_gamma[1] // bs)
        self.body_dofs = [on_gamma[0][body], on_gamma[1][body]]
        omega = np.atleast_1d(np.asarray(angular_velocity, dtype=np.float64))
        if omega.shape == (1,) and omega[0] == 0:  # the default: no rotation
            omega = np.zeros(len(self._rotations))
        if len(omega) != len(self._rotations):
            raise ValueError(
                f"angular_velocity: {len(self._rotations)} component(s) in {d}D, got {omega}"
            )
        for k, rot in enumerate(self._rotations):  # the nodes have moved
            rot.interpolate(partial(self._rigid.rotation, k))
        self._set_velocity(
            self.u_body, np.zeros(d) if boundary_velocity is None else boundary_velocity
        )
        for w, rot in zip(omega, self._rotations, strict=True):
            if w:
                self.u_body.x.array[:] += w * rot.x.array
        wall = on_gamma[1][~body]
        self.u_body.x.array[wall] = self.u_wall.x.array[wall]
        dofs = self.body_dofs[1]
        for i, w in enumerate(self._tests):
            w.x.array[:] = 0.0
            if i < d:  # unrolled: component i at the dofs = i (mod d)
                w.x.array[dofs[dofs % d == i]] = 1.0
            else:
                w.x.array[dofs] = self._rotations[i - d].x.array[dofs]
        return [self.bc_wall, fem.dirichletbc(self.u_body, on_gamma, W.sub(0)), self.bc_pressure]

    def solve(
        self,
        boundary_velocity: VelocityData | None = None,
        angular_velocity: npt.ArrayLike = 0.0,
    ) -> tuple[fem.Function, fem.Function]:
        """Solve on the current domain; return collapsed copies ``(u_h, p_h)`` (collective).

        ``boundary_velocity`` (constant ``(gdim,)`` or ``x -> (gdim, n)``) plus
        ``angular_velocity x x`` is the velocity of the bodies on Gamma_h.
        The solution stays in :attr:`wh`; use :meth:`assemble` and :meth:`solve_assembled`
        to time the stages.
        """
        self.assemble(boundary_velocity, angular_velocity)
        self.solve_assembled()
        return self.wh.sub(0).collapse(), self.wh.sub(1).collapse()

    def assemble(
        self,
        boundary_velocity: VelocityData | None = None,
        angular_velocity: npt.ArrayLike = 0.0,
    ) -> None:
        """Boundary conditions of the current step and assembly into the same matrix."""
        self.problem.assemble(self.boundary_conditions(boundary_velocity, angular_velocity))

    def solve_assembled(self) -> fem.Function:
        """Solve what :meth:`assemble` assembled into :attr:`wh`."""
        return self.problem.solve_assembled()

    def _sum(self, forms: Sequence[fem.Form]) -> npt.NDArray[np.float64]:
        comm = self.md.comm
        return np.array([comm.allreduce(fem.assemble_scalar(f)) for f in forms])

    def force(self) -> npt.NDArray[np.float64]:
        """Fluid force on the bodies, ``(gdim,)``, from the weak residual (collective)."""
        return self._sum([f.step() for f in self._reaction[: self.gdim]])

    def torque(self) -> Any:
        """Fluid torque on the bodies about the origin from the weak residual (collective):
        a float in 2D, ``(3,)`` in 3D."""
        return self._rigid.torque(self._sum([f.step() for f in self._reaction[self.gdim :]]))

    def surface_force(self) -> npt.NDArray[np.float64]:
        """Fluid force on Gamma_h, ``(gdim,)``: ``-int_Gamma_h sigma n ds`` (collective)."""
        return self._sum([f.step() for f in self._surface[: self.gdim]])

    def surface_torque(self) -> Any:
        """Fluid torque about the origin, ``int_Gamma_h x x (sigma nu) ds`` (collective):
        a float in 2D, ``(3,)`` in 3D."""
        return self._rigid.torque(self._sum([f.step() for f in self._surface[self.gdim :]]))
