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

import basix.ufl
import numpy as np
import numpy.typing as npt
import ufl
from dolfinx import fem

from dolfinx_universal.boundaries.base import Boundary
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
    onto the current nodes, combined) and the mesh velocity :attr:`w`.

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

    # -- stepping -------------------------------------------------------------------------

    def initialize(
        self, u0: fem.Function, dudt: ufl.core.expr.Expr | fem.Function | None = None
    ) -> None:
        """Take ``u0`` (on the current mesh, at ``t0``) as the initial value.

        ``dudt``, the time derivative ``∂_t u`` at ``t0`` (a UFL expression, e.g. from the
        PDE and the initial data, or a function), lets the first steps be taken by
        ESDIRK3 (its explicit first stage needs it). Without it they are taken by SDIRK3,
        whose first step, with time-dependent boundary data, is accurate to second order
        only (its stage order is 1): this bounds the error of the whole run by ``C dt^2``.
        """
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
        if self.scheme in TABLEAUX or len(self._levels) < self.order:
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
