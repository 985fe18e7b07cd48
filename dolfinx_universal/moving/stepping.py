"""Time integration on a moving domain: an ALE form on the nodes of each step's triangulation.

The solution of a step lives on that step's mesh (its nodes and active cells). A step from
``t_n`` to ``t_{n+1}`` conforms the background to ``Gamma(t_{n+1})`` and keeps that
triangulation fixed over the integrator's stencil: the nodes it takes for the earlier
positions of Gamma (:meth:`~dolfinx_universal.moving.domain.MovingDomain.nodes_at`) are
smooth paths in time, and along them

.. math:: \\frac{d}{dt} u(x(t), t) = \\partial_t u + w \\cdot \\nabla u,
          \\qquad w = \\dot x,

so that a PDE ``∂_t u + A(u) = f`` becomes an ODE for the dof values along the paths with
the ALE term ``- w · ∇u`` (the non-conservative ALE form). The previous solutions are
carried onto the paths by :class:`~dolfinx_universal.moving.transfer.NodeTransfer`: exactly
where the triangulation did not change, by evaluation (and, for cells that have just
entered the domain, extension from the nearest old cell) where it did. This is the scheme
of Gawlik & Lew (2014): the universal mesh's map is smooth in time for a fixed
triangulation, and the triangulation changes only at step boundaries.

The user writes one UFL form for every step and stage, with the time derivative
:meth:`TimeStepper.time_derivative`; the integrator sets its constants and functions.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from mpi4py import MPI
from petsc4py import PETSc

import basix.ufl
import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem
from dolfinx.io import vtkhdf

from dolfinx_universal.boundaries.base import Boundary
from dolfinx_universal.moving import checkpoint
from dolfinx_universal.moving.domain import MovingDomain
from dolfinx_universal.moving.transfer import node_transfer

__all__ = ["SCHEMES", "TimeStepper", "derivative_weights"]

_GAMMA = 0.43586652150845899942
SDIRK3 = (
    np.array(
        [
            [_GAMMA, 0.0, 0.0],
            [(1 - _GAMMA) / 2, _GAMMA, 0.0],
            [-3 * _GAMMA**2 / 2 + 4 * _GAMMA - 0.25, 3 * _GAMMA**2 / 2 - 5 * _GAMMA + 1.25, _GAMMA],
        ]
    ),
    np.array([_GAMMA, (1 + _GAMMA) / 2, 1.0]),
)
"""Alexander's three-stage SDIRK (1977): order 3, L-stable, stiffly accurate (the last
stage is the step's value): Butcher matrix and nodes."""

_C2 = 2 * _GAMMA
_A32 = (0.18 - 0.6 * _GAMMA) / _C2
_B = np.linalg.solve(
    np.array([[1.0, 1.0, 1.0], [0.0, _C2, 0.6], [0.0, _C2**2, 0.36]]),
    np.array([1 - _GAMMA, 0.5 - _GAMMA, 1 / 3 - _GAMMA]),
)
ESDIRK3 = (
    np.array(
        [
            [0.0, 0.0, 0.0, 0.0],
            [_GAMMA, _GAMMA, 0.0, 0.0],
            [0.6 - _GAMMA - _A32, _A32, _GAMMA, 0.0],
            [_B[0], _B[1], _B[2], _GAMMA],
        ]
    ),
    np.array([0.0, _C2, 0.6, 1.0]),
)
"""The four-stage ESDIRK of order 3 and stage order 2 with ``c_3 = 3/5`` and Alexander's
``gamma``: L-stable and stiffly accurate (the implicit part of Kennedy & Carpenter's
ARK3(2)4L[2]SA, Appl. Numer. Math. 44, 2003); its coefficients here are solved from the
order and stage-order conditions. Its stage order 2 keeps order 3 with time-dependent
Dirichlet data, where SDIRK3 (stage order 1) falls to about 2.4."""

TABLEAUX = {"SDIRK3": SDIRK3, "ESDIRK3": ESDIRK3}

SCHEMES = {"BDF1": 1, "BDF2": 2, "BDF3": 3, "SDIRK3": 3, "ESDIRK3": 3}
"""The integrators and their orders."""


def derivative_weights(nodes: npt.ArrayLike, at: float) -> npt.NDArray[np.float64]:
    """Weights ``c`` with ``p'(at) = sum_j c_j p(nodes_j)`` for every polynomial ``p`` of
    degree ``len(nodes) - 1``: the derivatives of the Lagrange basis at ``at``. At
    ``at = nodes[0]`` with steps ``dt`` these are the variable-step BDF coefficients
    divided by ``dt``."""
    tau = np.asarray(nodes, dtype=np.float64)
    n = len(tau)
    c = np.zeros(n)
    for j in range(n):
        others = np.delete(tau, j)
        denom = np.prod(tau[j] - others)
        total = 0.0
        for m in range(n - 1):  # d/dt prod_{m} (t - others_m) at ``at``
            total += np.prod(np.delete(at - others, m))
        c[j] = total / denom
    return c


def _extrapolation(nodes: list[float], at: float) -> npt.NDArray[np.float64]:
    """The Lagrange basis of ``nodes`` at ``at``: weights extrapolating values there."""
    tau = np.asarray(nodes)
    return np.array([np.prod([(at - tau[m]) / (tau[j] - tau[m]) for m in range(len(tau)) if m != j])
                     for j in range(len(tau))])  # fmt: skip


def _combine(
    weights: npt.NDArray[np.float64],
    arrays: list[npt.NDArray[np.float64]],
    like: npt.NDArray[np.float64] | None = None,
) -> npt.NDArray[np.float64]:
    """``sum_j weights_j arrays_j`` (zeros like ``like`` for no arrays)."""
    out = np.zeros_like(arrays[0] if arrays else like)
    for c, a in zip(weights, arrays, strict=True):
        out += c * a
    return out


_Array = npt.NDArray[np.float64]
_Slope = tuple[_Array, _Array]
"""A Runge–Kutta step's final slope (dof values) and the nodes' velocity there."""


@dataclass
class _Level:
    """One step's solution: its time, boundary, nodes, active cells and dof values."""

    t: float
    boundary: Boundary
    x: npt.NDArray[np.float64]
    active: npt.NDArray[np.bool_]
    values: npt.NDArray[np.float64]
    slope: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None = None
    """The final slope along the step's paths and the nodes' velocity there (Runge–Kutta
    steps)."""


class TimeStepper:
    """Implicit time steps of ``∂_t u + A(u) = f`` on a moving domain, in ALE form.

    Write the problem with :meth:`time_derivative` in place of ``∂_t u``, once::

        ts = TimeStepper(md, V, motion, t0=0.0, dt=0.01, scheme="BDF2")
        F = md.active * (ts.time_derivative(u) * v + inner(grad(u), grad(v)) - f(ts.t) * v) * dx

    where ``md`` has been updated to ``motion(t0)``; give the initial value with
    :meth:`initialize`, then call :meth:`advance` with a function that assembles and solves
    the problem (at the time :attr:`t` on the current mesh) and returns the solution.
    Forms are compiled once: the integrator only sets :attr:`t`, :attr:`dt`, the
    coefficient :attr:`alpha`, the function :attr:`history` (the previous solutions carried
    onto the current nodes, combined) and the mesh velocity :attr:`w`. A run is saved with
    :meth:`write_checkpoint` and continued, by a stepper built in the same way (on any
    number of ranks), after :meth:`read_checkpoint`.

    Parameters
    ----------
    md
        The moving domain, updated to ``motion(t0)``.
    V
        The solution's space (a scalar or blocked Lagrange space on ``md.mesh``).
    motion
        ``t -> Boundary``: the domain at time ``t`` (called again for earlier times).
    t0, dt
        Initial time and time step.
    scheme
        ``"BDF1"``, ``"BDF2"``, ``"BDF3"`` (variable-step coefficients; the first steps by
        ESDIRK3 when :meth:`initialize` is given the initial time derivative, else by
        SDIRK3), ``"ESDIRK3"`` (:data:`ESDIRK3`: order 3, stage order 2) or ``"SDIRK3"``
        (:data:`SDIRK3`: order 3, stage order 1).

    Notes
    -----
    Runge–Kutta methods lose order on stiff problems with time-dependent boundary data,
    towards their stage order: on the heat equation on a moving domain ESDIRK3 reaches
    about 2-2.5 and SDIRK3 about 2, while BDF-p keeps p (see the documentation page on
    time-dependent problems).
    """

    def __init__(
        self,
        md: MovingDomain,
        V: fem.FunctionSpace,
        motion: Callable[[float], Boundary],
        t0: float,
        dt: float,
        scheme: str = "BDF2",
    ) -> None:
        if scheme not in SCHEMES:
            raise ValueError(f"unknown scheme {scheme!r}: choose one of {sorted(SCHEMES)}")
        if md.boundary is None:
            raise RuntimeError("update the moving domain to motion(t0) first")
        self.md, self.V, self.motion, self.scheme = md, V, motion, scheme
        self.order = SCHEMES[scheme]
        mesh = md.mesh
        self.t = fem.Constant(mesh, float(t0))
        """The time of the equation being solved (a step's or a stage's)."""
        self.time_variable = ufl.variable(self.t)
        """:attr:`t` as a UFL variable: write time-dependent data with it so that
        ``ufl.diff(g, ts.time_variable)`` is its time derivative."""
        self._data: list[tuple[fem.Expression, fem.Expression, fem.Function]] = []
        self.dt = fem.Constant(mesh, float(dt))
        """The time step."""
        self.alpha = fem.Constant(mesh, 1.0)
        """The coefficient of the unknown in :meth:`time_derivative`."""
        self.history = fem.Function(V, name="history")
        """The previous solutions carried onto the current nodes, combined."""
        self.extrapolation = fem.Function(V, name="extrapolation")
        """The solution at the time :attr:`t` extrapolated from the previous ones on the
        current nodes: of the scheme's order for BDF (for a semi-implicit treatment of
        nonlinear terms, such as the convection of Navier–Stokes), the last stage's value
        in a Runge–Kutta step (first order)."""
        gdim = md.tdim
        element = basix.ufl.element(
            "Lagrange",
            mesh.basix_cell(),
            md.degree,
            basix.LagrangeVariant.gll_warped,
            shape=(gdim,),
        )
        self.W = fem.functionspace(mesh, element)
        self.w = fem.Function(self.W, name="mesh_velocity")
        """The mesh velocity: the time derivative of the nodes' paths."""
        imap = self.W.dofmap.index_map
        node = np.empty(imap.size_local + imap.num_ghosts, dtype=np.int64)
        node[self.W.dofmap.list] = mesh.geometry.dofmaps[0]  # the same element: a node each
        self._node_of_dof = node
        self.transfer = node_transfer(mesh, md.universal.cell_vertices, V)
        self._levels: list[_Level] = []
        self._bdf_start = False
        self._t_start = 0.0  # the initial value's time (an impulsive start's state before)
        self._orders: tuple[checkpoint.DofOrder, checkpoint.DofOrder] | None = None
        self.timings = dict.fromkeys(("update", "nodes", "transfer", "solve"), 0.0)
        """Seconds spent (this rank) in the domain's updates, the nodes' paths, the
        transfers and the user's solves."""

    # -- what the form uses ---------------------------------------------------------------

    def time_derivative(self, u: ufl.core.expr.Expr, part: int | None = None) -> ufl.core.expr.Expr:
        """``∂_t u`` of the integrator in ALE form: ``(alpha u - history) / dt - ∇u · w``.

        ``part``: for a mixed space, the index of ``u`` among ``ufl.split`` of the unknown
        (the velocity of a Taylor–Hood pair: ``part=0``)."""
        h = self.history if part is None else ufl.split(self.history)[part]
        return (self.alpha * u - h) / self.dt - ufl.dot(ufl.grad(u), self.w)

    def dirichlet_data(
        self, g: ufl.core.expr.Expr, space: fem.FunctionSpace | None = None
    ) -> fem.Function:
        """The values of ``g`` (a UFL expression of ``x`` and :attr:`time_variable`) that a
        Dirichlet condition on the moving boundary should take at each step and stage.

        BDF steps take ``g`` at the step's time. Runge–Kutta stages take the stage values
        the method gives the ODE ``d/dt g(x(t), t) = ∂_t g + ∇g · w`` along the nodes'
        paths: the exact values there would lower SDIRK3 to about second order in time
        (the stage order is 1; Carpenter, Gottlieb, Abarbanel & Don, SIAM J. Sci. Comput.
        16, 1995; Alonso-Mallo & Cano, 2002). The returned function (on :attr:`V`) is
        updated before every call of ``solve``; use it in ``fem.dirichletbc``.
        ``space``: the space of the data (default :attr:`V`; for a mixed space the
        collapsed sub-space the condition applies to).
        """
        space = self.V if space is None else space
        points = space.element.interpolation_points
        value = fem.Expression(g, points)
        rate = fem.Expression(
            ufl.diff(g, self.time_variable) + ufl.dot(ufl.grad(g), self.w), points
        )
        data = fem.Function(space, name="dirichlet_data")
        self._data.append((value, rate, data))
        return data

    @property
    def time(self) -> float:
        """The time of the last solution."""
        return self._levels[-1].t if self._levels else float(self.t.value)

    # -- checkpoints ----------------------------------------------------------------------

    def write_checkpoint(self, path: str | Path) -> None:
        """Write the state of the run to the VTKHDF file ``path`` (collective).

        The file (HDF5; name it ``*.vtkhdf``) opens in ParaView: DOLFINx writes the current
        mesh (the whole background with its current nodes) and, as point data ``u`` at the
        time of the last solution, that solution at the geometry nodes (interpolated into
        the geometry's Lagrange space; the components of a mixed space's sub-functions side
        by side; NaN at the nodes of no active cell, outside the domain). The group
        ``/TimeStepper`` (:mod:`~dolfinx_universal.moving.checkpoint`) holds what
        :meth:`read_checkpoint` needs to continue the run exactly: the scheme, the time
        step, the start (``initialize``'s ``start``), and for each of the last solutions
        kept its time, dof values and
        Runge–Kutta slope. The nodes and active cells of these solutions are not stored:
        they are those of the domain updated to ``motion(t)``. Dof values are stored in an
        order that does not depend on the number of ranks. An existing file is replaced.

        Parameters
        ----------
        path
            The file to write.

        Raises
        ------
        RuntimeError
            Before :meth:`initialize` (on every rank).
        """
        if not self._levels:
            raise RuntimeError("nothing to write: give the initial value first (initialize)")
        md, newest = self.md, self._levels[-1]
        u = fem.Function(self.V)
        u.x.array[:] = newest.values
        data = checkpoint.point_values(u, md.degree, md.active_mask)
        vtkhdf.write_mesh(str(path), md.mesh)
        vtkhdf.write_point_data(str(path), md.mesh, data.ravel(), newest.t)
        values, nodes = self._dof_orders()
        viewer = checkpoint.open_viewer(path, "a", md.comm)
        try:
            checkpoint.write_small(viewer, "format", [checkpoint.FORMAT_VERSION])
            checkpoint.write_small(viewer, "scheme", [ord(c) for c in self.scheme])
            checkpoint.write_small(viewer, "dt", [float(self.dt.value)])
            checkpoint.write_small(viewer, "bdf_start", [float(self._bdf_start), self._t_start])
            checkpoint.write_small(viewer, "times", [lv.t for lv in self._levels])
            checkpoint.write_small(
                viewer, "has_slope", [lv.slope is not None for lv in self._levels]
            )
            checkpoint.write_small(viewer, "sizes", [values.size, nodes.size, md.comm.size])
            nodes.write(viewer, "background", self._by_dof(md._x0))
            for i, lv in enumerate(self._levels):
                values.write(viewer, f"values_{i}", lv.values)
                if lv.slope is not None:
                    values.write(viewer, f"slope_{i}", lv.slope[0])
                    nodes.write(viewer, f"velocity_{i}", self._by_dof(lv.slope[1]))
        finally:
            viewer.destroy()

    def read_checkpoint(self, path: str | Path, u: fem.Function | None = None) -> fem.Function:
        """Continue a run from the file ``path`` of :meth:`write_checkpoint` (collective).

        The stepper must have been built as the one that wrote the file: the same
        background, space, motion and scheme (the initial time and step are taken from the
        file), on any number of ranks. It takes the file's time step and last solutions,
        updating the moving domain to ``motion(t)`` for each of their times in turn (the
        latest last): :meth:`advance` then takes the step that the writer would have
        taken next. No :meth:`initialize` is needed.

        Parameters
        ----------
        path
            A file written by :meth:`write_checkpoint`.
        u
            A function of :attr:`V` to receive the last solution (default: a new one).

        Returns
        -------
        The last solution, at the time :attr:`time`.

        Raises
        ------
        FileNotFoundError
            If there is no file ``path``.
        ValueError
            If the file holds no checkpoint of this format, or one of another scheme, of
            another number of dofs or nodes, or of a background whose nodes differ (another
            background, or one whose cells are numbered otherwise: a background that
            :func:`~dolfinx_universal.io.redistribute` partitioned, as
            :meth:`~dolfinx_universal.moving.domain.MovingDomain.from_motion` does on
            several ranks, numbers its cells by the ranks' partition, so its checkpoints are
            read on the same number of ranks only). Every rank raises, and nothing is changed.
        """
        md = self.md
        kind = md.comm.bcast(checkpoint.file_kind(path) if md.comm.rank == 0 else None, root=0)
        if kind == "missing":
            raise FileNotFoundError(f"no checkpoint file {path}")
        if kind != "hdf5":
            raise ValueError(f"{path} is no HDF5 file")
        if u is not None and u.x.array.size != self.history.x.array.size:
            raise ValueError("u must be a function of the stepper's space V")
        viewer = checkpoint.open_viewer(path, "r", md.comm)
        try:
            head, stored = self._read_state(viewer, path)
        except PETSc.Error:
            raise ValueError(
                f"{path} holds no complete TimeStepper checkpoint (datasets of the group "
                f"{checkpoint.GROUP} are missing)"
            ) from None
        finally:
            viewer.destroy()
        levels = []
        for t, (level_values, slope) in zip(head["times"], stored, strict=True):
            boundary = self.motion(float(t))
            md.update(boundary)
            levels.append(
                _Level(float(t), boundary, self._nodes(), md.active_mask.copy(), level_values,
                       slope)
            )  # fmt: skip
        self._levels = levels
        self.dt.value = float(head["dt"][0])
        self._bdf_start = bool(head["bdf_start"][0])
        self._t_start = float(head["bdf_start"][1])
        self.t.value = levels[-1].t
        u = fem.Function(self.V, name="u") if u is None else u
        u.x.array[:] = levels[-1].values
        return u

    def _read_state(
        self, viewer: PETSc.ViewerHDF5, path: str | Path
    ) -> tuple[dict[str, npt.NDArray[np.float64]], list[tuple[_Array, _Slope | None]]]:
        """The header of a checkpoint, checked, and each stored solution's dof values and
        slope (collective)."""
        values, nodes = self._dof_orders()
        head = {
            name: checkpoint.read_small(viewer, name)
            for name in ("format", "scheme", "dt", "bdf_start", "times", "has_slope", "sizes")
        }
        self._check_checkpoint(path, head, values, nodes)
        md = self.md
        background = self._by_node(nodes.read(viewer, "background"))
        scale = md.comm.allreduce(float(np.abs(md._x0).max(initial=1.0)), op=MPI.MAX)
        gap = md.comm.allreduce(float(np.abs(background - md._x0).max(initial=0.0)), op=MPI.MAX)
        if gap > 1e-12 * scale:
            raise ValueError(
                f"{path} was written on another background, or on one whose cells are "
                f"numbered otherwise (its nodes differ by {gap:.3g}): a background "
                "partitioned by dolfinx_universal.io.redistribute (as "
                "MovingDomain.from_motion does on several ranks) numbers its cells by "
                f"the partition (the file comes from a run on {int(head['sizes'][2])} "
                f"rank(s), this one has {md.comm.size})"
            )
        stored = []
        for i, has_slope in enumerate(head["has_slope"]):
            slope = None
            if has_slope:
                slope = (
                    values.read(viewer, f"slope_{i}"),
                    self._by_node(nodes.read(viewer, f"velocity_{i}")),
                )
            stored.append((values.read(viewer, f"values_{i}"), slope))
        return head, stored

    def _check_checkpoint(
        self,
        path: str | Path,
        head: dict[str, npt.NDArray[np.float64]],
        values: checkpoint.DofOrder,
        nodes: checkpoint.DofOrder,
    ) -> None:
        """Raise (on every rank: the file's header is the same there) if the checkpoint
        does not fit this stepper."""
        version = int(head["format"][0])
        if version != checkpoint.FORMAT_VERSION:
            raise ValueError(
                f"{path}: checkpoint format {version}, this version reads "
                f"{checkpoint.FORMAT_VERSION}"
            )
        scheme = "".join(chr(int(c)) for c in head["scheme"])
        if scheme != self.scheme:
            raise ValueError(
                f"{path} was written by a {scheme} stepper, this one is {self.scheme}: "
                "build the stepper with the scheme of the run"
            )
        num_values, num_nodes = int(head["sizes"][0]), int(head["sizes"][1])
        if (num_values, num_nodes) != (values.size, nodes.size):
            raise ValueError(
                f"{path} holds {num_values} dof values and {num_nodes} node coordinates, "
                f"this stepper's space and mesh have {values.size} and {nodes.size}: build "
                "it on the background and space of the run"
            )
        count = len(head["times"])
        if not 1 <= count <= max(self.order, 1) or len(head["has_slope"]) != count:
            raise ValueError(
                f"{path}: {count} stored solutions, a {scheme} run keeps 1-{self.order}"
            )

    def _dof_orders(self) -> tuple[checkpoint.DofOrder, checkpoint.DofOrder]:
        """The file orders of the dofs of :attr:`V` and of the nodes (through :attr:`W`),
        made at the first checkpoint (collective)."""
        if self._orders is None:
            self._orders = (checkpoint.DofOrder(self.V), checkpoint.DofOrder(self.W))
        return self._orders

    def _by_dof(self, nodes: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """A node array ``(num_nodes, tdim)`` as the dof values of :attr:`W`."""
        return nodes[self._node_of_dof, : self.md.tdim].ravel()

    def _by_node(self, values: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """The dof values of :attr:`W` as a node array ``(num_nodes, tdim)``."""
        out = np.empty((len(self._node_of_dof), self.md.tdim))
        out[self._node_of_dof] = values.reshape(-1, self.md.tdim)
        return out

    # -- stepping -------------------------------------------------------------------------

    def initialize(
        self,
        u0: fem.Function,
        dudt: ufl.core.expr.Expr | fem.Function | None = None,
        start: str | None = None,
    ) -> None:
        """Take ``u0`` (on the current mesh, at ``t0``) as the initial value.

        ``dudt``, the time derivative ``∂_t u`` at ``t0`` (a UFL expression, e.g. from the
        PDE and the initial data, or a function), lets the first steps be taken by
        ESDIRK3 (its explicit first stage needs it). Without it they are taken by SDIRK3,
        whose first step, with time-dependent boundary data, is accurate to second order
        only (its stage order is 1): this bounds the error of the whole run by ``C dt^2``.

        ``start="BDF"`` is for an impulsive start, where ``u0`` does not meet the boundary
        data (a body set in motion in a fluid at rest): ``u0`` is the state before the
        data's jump, and only the first step starts from it. The first two steps are then
        taken by BDF1 and the next ones by BDF of increasing order (BDF2, ...). A jump is
        no smooth solution: the stages of a Runge–Kutta step resolve it with slopes of
        alternating sign, and a BDF2 formula reaching back to ``u0`` differentiates it
        with the wrong sign (their time derivative, hence a force computed from it, has
        the wrong sign); implicit Euler's difference quotient has the jump's sign. The
        start's local errors are of second order.
        """
        if start not in (None, "BDF"):
            raise ValueError(f"unknown start {start!r}: None or 'BDF'")
        self._bdf_start = start == "BDF" and self.scheme not in TABLEAUX
        self._t_start = float(self.t.value)
        md = self.md
        assert md.boundary is not None
        slope = None
        if dudt is not None:
            k = fem.Function(self.V)
            if isinstance(dudt, fem.Function):
                k.interpolate(dudt)
            else:
                k.interpolate(fem.Expression(dudt, self.V.element.interpolation_points))
            slope = (k.x.array.copy(), np.zeros_like(self._nodes()))  # at fixed places
        self._levels = [
            _Level(float(self.t.value), md.boundary, self._nodes(), md.active_mask.copy(),
                   u0.x.array.copy(), slope)
        ]  # fmt: skip

    def _nodes(self) -> npt.NDArray[np.float64]:
        return self.md.mesh.geometry.x[:, : self.md.tdim].copy()

    def _set_velocity(
        self, weights: npt.NDArray[np.float64], nodes: list[npt.NDArray[np.float64]]
    ) -> npt.NDArray[np.float64]:
        """Set :attr:`w` to the nodes' velocity ``sum_j weights_j nodes_j``; return it."""
        w = _combine(weights, nodes)
        self.w.x.array[:] = w[self._node_of_dof].ravel()
        return w

    def _carry(self, level: _Level, x: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        t0 = time.perf_counter()
        out = self.transfer.carry(level.values, level.x, level.active, x, self.md.active_mask)
        self.timings["transfer"] += time.perf_counter() - t0
        return out

    def _paths(self, boundaries: list[Boundary]) -> list[npt.NDArray[np.float64]]:
        t0 = time.perf_counter()
        x = self.md.nodes_at(boundaries)
        self.timings["nodes"] += time.perf_counter() - t0
        return x

    def advance(self, solve: Callable[[], fem.Function], dt: float | None = None) -> float:
        """One step (collective): update the domain, then solve each stage with ``solve``
        (which returns the solution on the current mesh at :attr:`t`). Returns the new
        time."""
        if not self._levels:
            raise RuntimeError("give the initial value first (initialize)")
        if dt is not None:
            self.dt.value = float(dt)
        step = float(self.dt.value)
        t1 = self._levels[-1].t + step
        boundary = self.motion(t1)
        t0 = time.perf_counter()
        self.md.update(boundary)
        self.timings["update"] += time.perf_counter() - t0
        slope = None
        if self.scheme in TABLEAUX or (len(self._levels) < self.order and not self._bdf_start):
            # Runge–Kutta, or the start of a BDF: ESDIRK3 where the last slope is known
            esdirk = self._levels[-1].slope is not None and self.scheme != "SDIRK3"
            values, slope = self._dirk(t1, step, solve, "ESDIRK3" if esdirk else "SDIRK3")
        else:
            values = self._bdf(t1, solve)
        self._levels.append(
            _Level(t1, boundary, self._nodes(), self.md.active_mask.copy(), values, slope)
        )
        del self._levels[: -max(self.order, 1)]
        return t1

    def _solve(self, solve: Callable[[], fem.Function]) -> npt.NDArray[np.float64]:
        t0 = time.perf_counter()
        u = solve()
        self.timings["solve"] += time.perf_counter() - t0
        return u.x.array.copy()

    def _bdf(self, t1: float, solve: Callable[[], fem.Function]) -> npt.NDArray[np.float64]:
        """A BDF step of the scheme's order to ``t1`` on the current triangulation."""
        levels = self._levels[::-1][: self.order]
        if self._bdf_start and len(levels) > 1:  # the state before the jump: step 1 only
            levels = [lv for lv in levels if lv.t != self._t_start]
        x1 = self._nodes()
        nodes = [x1, *self._paths([lv.boundary for lv in levels])]
        c = derivative_weights([t1] + [lv.t for lv in levels], t1)
        self._set_velocity(c, nodes)
        dt = float(self.dt.value)
        carried = [self._carry(lv, x) for lv, x in zip(levels, nodes[1:], strict=True)]
        history = -dt * _combine(c[1:], carried)
        self.extrapolation.x.array[:] = _combine(
            _extrapolation([lv.t for lv in levels], t1), carried
        )
        self.alpha.value = c[0] * dt
        self.history.x.array[:] = history
        self.t.value = t1
        for value, _, data in self._data:
            data.interpolate(value)
        return self._solve(solve)

    def _dirk(
        self, t1: float, step: float, solve: Callable[[], fem.Function], scheme: str
    ) -> tuple[npt.NDArray[np.float64], tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]:
        """A step of the diagonally implicit Runge–Kutta method ``scheme`` to ``t1``: its
        stages on the current triangulation's nodes for the stage times (written into the
        mesh for each stage's solve). An explicit first stage takes the last step's final
        slope, carried onto the current paths (first same as last). Returns the value at
        ``t1`` and the final slope with the nodes' velocity there."""
        A, cs = TABLEAUX[scheme]
        level = self._levels[-1]
        x1 = self._nodes()
        fractions = np.unique(np.concatenate([[0.0, 1.0], cs]))  # the paths' times
        times = level.t + step * fractions
        inner = [self.motion(float(t)) for t in times[1:-1]]
        nodes = [*self._paths([level.boundary, *inner]), x1]
        u0 = self._carry(level, nodes[0])
        geometry = self.md.mesh.geometry.x
        d = self.md.tdim
        data = self._start_data(nodes[0], float(times[0]))
        slopes: list[npt.NDArray[np.float64]] = []
        u = u0
        for i, path in enumerate(np.searchsorted(fractions, cs)):
            geometry[:, :d] = nodes[path]
            w = self._set_velocity(derivative_weights(times, times[path]), nodes)
            self.t.value = times[path]
            self._stage_data(data, A[i], step)
            if A[i, i] == 0.0:  # explicit: the slope at the start, along the new paths
                slopes.append(self._carry_slope(level, nodes[0], w))
                continue
            known = u0 + step * _combine(A[i, :i], slopes, like=u0)
            self.extrapolation.x.array[:] = u
            self.alpha.value = 1.0 / A[i, i]
            self.history.x.array[:] = known / A[i, i]
            u = self._solve(solve)
            slopes.append((u - known) / (step * A[i, i]))
        geometry[:, :d] = x1
        return u, (slopes[-1], _combine(derivative_weights(times, times[-1]), nodes))

    def _start_data(
        self, x0: npt.NDArray[np.float64], t0: float
    ) -> list[tuple[npt.NDArray[np.float64], list[npt.NDArray[np.float64]]]]:
        """The Dirichlet data at the step's start on the paths' nodes ``x0`` (and room for
        their rates at the stages)."""
        if not self._data:
            return []
        geometry, d = self.md.mesh.geometry.x, self.md.tdim
        saved = geometry[:, :d].copy()
        geometry[:, :d] = x0
        self.t.value = t0
        starts: list[tuple[npt.NDArray[np.float64], list[npt.NDArray[np.float64]]]] = []
        for value, _, data in self._data:
            data.interpolate(value)
            starts.append((data.x.array.copy(), []))
        geometry[:, :d] = saved
        return starts

    def _stage_data(
        self,
        starts: list[tuple[npt.NDArray[np.float64], list[npt.NDArray[np.float64]]]],
        row: npt.NDArray[np.float64],
        step: float,
    ) -> None:
        """Set the Dirichlet data of a stage (the mesh, time and velocity set to it): the
        method's stage value for the data's rate along the paths."""
        for (_, rate, data), (g0, rates) in zip(self._data, starts, strict=True):
            data.interpolate(rate)
            rates.append(data.x.array.copy())
            data.x.array[:] = g0 + step * _combine(row[: len(rates)], rates)

    def _carry_slope(
        self, level: _Level, x: npt.NDArray[np.float64], w: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]:
        t0 = time.perf_counter()
        slope, velocity = level.slope  # type: ignore[misc]
        out = self.transfer.carry_slope(
            slope, level.values, velocity, level.x, level.active, x, w, self.md.active_mask
        )
        self.timings["transfer"] += time.perf_counter() - t0
        return out
