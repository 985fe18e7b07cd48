"""Checkpoints of time steps on moving domains: a run written at one step and continued by a
new stepper that reads the file, on the same or another number of ranks.

The heat equation (P2 on a degree-2 moving domain, Dirichlet data on the ellipse that
translates and rotates through the background) runs :data:`STEPS` steps; a checkpoint is
written after :data:`AT`. Tests marked ``mpi`` also run in-process under mpirun (``.ci/test``:
2 and 3 ranks); the change of the number of ranks compares a serial run (``COMM_SELF`` on
every rank) with the parallel one.
"""

from __future__ import annotations

from mpi4py import MPI
from petsc4py import PETSc

import basix.ufl
import numpy as np
import pytest
import ufl
from conftest import needs_ranks
from dolfinx import fem
from dolfinx.io import vtkhdf

import dolfinx_universal as du
from dolfinx_universal.core.collective import vertex_reduce
from dolfinx_universal.moving.checkpoint import dof_keys
from dolfinx_universal.moving.problems import MovingLinearProblem
from dolfinx_universal.moving.stepping import TimeStepper

comm = MPI.COMM_WORLD
STEPS, AT = 6, 3


def _ellipse(t: float) -> du.Domain:
    """An ellipse translating and rotating through the background."""
    return du.Domain(du.Ellipse([0.3 * np.sin(2 * t), 0.2 * t], 0.55, 0.4, angle=t))


def _domain(c, degree: int = 2) -> du.MovingDomain:
    md = du.MovingDomain(du.equilateral_mesh(c, [[-1.0, -0.9], [1.0, 1.0]], 0.1), degree=degree)
    md.update(_ellipse(0.0))
    return md


class _Heat:
    """``u_t - Δu = f`` with a solution that is no polynomial in space, on the moving
    ellipse: one stepper, its forms and its solve."""

    def __init__(self, scheme: str, c=comm, degree: int = 2) -> None:
        self.md = md = _domain(c, degree)
        self.V = V = fem.functionspace(md.mesh, ("Lagrange", degree))
        self.ts = ts = TimeStepper(md, V, _ellipse, 0.0, 0.05, scheme)
        x, t = ufl.SpatialCoordinate(md.mesh), ts.time_variable
        self.exact = (
            ufl.sin(3 * t) + ufl.cos(2 * t) * x[0] * x[1] + 0.5 * ufl.sin(2 * t) * x[1] ** 2
        )
        f = ufl.diff(self.exact, t) - ufl.div(ufl.grad(self.exact))
        u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
        F = md.active * (ts.time_derivative(u) * v + ufl.inner(ufl.grad(u), ufl.grad(v))) * ufl.dx
        F -= md.active * f * v * ufl.dx
        self.uh = fem.Function(V)
        self.problem = MovingLinearProblem(
            md, ufl.lhs(F), ufl.rhs(F), u=self.uh, petsc_options_prefix=f"checkpoint_{id(self)}_",
            petsc_options={"ksp_type": "preonly", "pc_type": "lu"}, active_only=True,
        )  # fmt: skip
        self.g = ts.dirichlet_data(self.exact)

    def start(self) -> None:
        u0 = fem.Function(self.V)
        u0.interpolate(fem.Expression(self.exact, self.V.element.interpolation_points))
        self.ts.initialize(u0, ufl.diff(self.exact, self.ts.time_variable))

    def run(self, steps: int) -> None:
        bc = [fem.dirichletbc(self.g, self.md.immersed_dofs(self.V))]
        for _ in range(steps):
            self.ts.advance(lambda: self.problem.solve(bc))

    def levels(self) -> list[tuple]:
        """Copies of the stepper's state: per level the time, nodes, active cells, values
        and slope."""
        return [
            (lv.t, lv.x.copy(), lv.active.copy(), lv.values.copy(),
             None if lv.slope is None else (lv.slope[0].copy(), lv.slope[1].copy()))
            for lv in self.ts._levels
        ]  # fmt: skip

    @property
    def final(self) -> np.ndarray:
        return self.ts._levels[-1].values.copy()


def _sorted(V: fem.FunctionSpace, values: np.ndarray) -> np.ndarray:
    """The owned dof values of ``V`` on all ranks, sorted by their rank-independent keys."""
    imap, bs = V.dofmap.index_map, V.dofmap.index_map_bs
    owned = imap.size_local * bs
    c = V.mesh.comm
    keys = np.concatenate(c.allgather(dof_keys(V)[:owned]))
    return np.concatenate(c.allgather(values[:owned]))[np.argsort(keys)]


def _sorted_levels(heat: _Heat, levels: list[tuple]) -> list[tuple]:
    """:meth:`_Heat.levels` with the values, slopes and node arrays sorted by key (through
    the stepper's vector space of the nodes)."""
    ts = heat.ts
    out = []
    for t, x, _, values, slope in levels:
        s = None if slope is None else (
            _sorted(ts.V, slope[0]), _sorted(ts.W, ts._by_dof(slope[1]))
        )  # fmt: skip
        out.append((t, _sorted(ts.W, ts._by_dof(x)), _sorted(ts.V, values), s))
    return out


@pytest.mark.mpi
@pytest.mark.parametrize("scheme", ["BDF2", "ESDIRK3"])
def test_restart_continues_the_run_exactly(scheme, mpi_tmp_path):
    """A stepper built anew reads the checkpoint written after step AT and continues to
    STEPS. The stored solutions come back bitwise, ghosts included, and so do their nodes
    and active cells, which are not stored but recomputed by updating the domain to each
    stored time in turn: an update depends only on the boundary and on the previous
    update's cells, which the replay repeats. The final solution then equals the
    uninterrupted run's (the same operations on the same numbers on the same ranks;
    measured: bitwise; rtol 1e-12 leaves room for a solver whose reductions are not
    reproducible). BDF2 stores two solutions (no slopes), ESDIRK3 three with their final
    slopes and the nodes' velocities."""
    path = mpi_tmp_path / f"{scheme}.vtkhdf"
    run = _Heat(scheme)
    run.start()
    run.run(AT)
    run.ts.write_checkpoint(path)
    saved = run.levels()
    run.run(STEPS - AT)

    again = _Heat(scheme)
    u = again.ts.read_checkpoint(path, again.uh)
    assert u is again.uh and again.ts.time == saved[-1][0]
    assert again.ts.dt.value == run.ts.dt.value
    restored = again.levels()
    assert len(restored) == len(saved) == (2 if scheme == "BDF2" else 3)
    for (t, x, active, values, slope), (t2, x2, active2, values2, slope2) in zip(
        saved, restored, strict=True
    ):
        assert t == t2
        np.testing.assert_array_equal(x, x2)  # the replayed updates: bitwise the same nodes
        np.testing.assert_array_equal(active, active2)
        np.testing.assert_array_equal(values, values2)
        assert (slope is None) == (slope2 is None) == (scheme == "BDF2")
        if slope is not None:
            np.testing.assert_array_equal(slope[0], slope2[0])
            np.testing.assert_array_equal(slope[1], slope2[1])
    np.testing.assert_array_equal(u.x.array, saved[-1][3])
    again.run(STEPS - AT)
    np.testing.assert_allclose(again.final, run.final, rtol=1e-12, atol=1e-14)


@pytest.mark.mpi
def test_restart_during_a_bdf_start(mpi_tmp_path):
    """A BDF3 run started by BDF of increasing order (``start="BDF"``), saved after its
    first step (one stored solution, fewer than the order), continues with the BDF start's
    second step, not a Runge–Kutta step: the final solution equals the uninterrupted
    run's (with a Runge–Kutta step instead it differs by the two methods' errors: 1e-3
    here)."""
    path = mpi_tmp_path / "bdf_start.vtkhdf"
    run = _Heat("BDF3")
    u0 = fem.Function(run.V)
    u0.interpolate(fem.Expression(run.exact, run.V.element.interpolation_points))
    run.ts.initialize(u0, start="BDF")
    run.run(1)
    run.ts.write_checkpoint(path)
    run.run(3)
    again = _Heat("BDF3")
    again.ts.read_checkpoint(path, again.uh)
    again.run(3)
    np.testing.assert_allclose(again.final, run.final, rtol=1e-12, atol=1e-14)


@pytest.mark.mpi
@needs_ranks(2)
def test_restart_on_another_number_of_ranks(mpi_tmp_path):
    """A checkpoint of a serial run continues on all ranks and one of the parallel run
    continues in serial (ESDIRK3: values, slopes and node velocities). The stored arrays
    come back bitwise at the same dofs (matched by their rank-independent keys); the
    replayed nodes equal the writer's to rounding (measured 3.3e-16 on 2 and 3 ranks: a
    node is computed in another cell, or in another order, than in serial). Continued,
    each run ends within rounding of the uninterrupted run on its own number of ranks
    (measured 4.4e-16 on 2 and 3 ranks, for solutions of size 1; serial and parallel
    uninterrupted runs differ by 3.9e-15 and 4.4e-15): the restart adds nothing to what
    the number of ranks changes."""
    serial_path = str(mpi_tmp_path / "serial.vtkhdf")  # a str or a Path
    parallel_path = mpi_tmp_path / "parallel.vtkhdf"
    serial = _Heat("ESDIRK3", MPI.COMM_SELF)  # the same serial run on every rank
    serial.start()
    serial.run(AT)
    if comm.rank == 0:
        serial.ts.write_checkpoint(serial_path)
    serial_saved = _sorted_levels(serial, serial.levels())
    serial.run(STEPS - AT)
    parallel = _Heat("ESDIRK3")
    parallel.start()
    parallel.run(AT)
    parallel.ts.write_checkpoint(parallel_path)
    parallel_saved = _sorted_levels(parallel, parallel.levels())
    parallel.run(STEPS - AT)
    comm.barrier()  # the serial file is written

    for reader, saved, path, whole in (
        (_Heat("ESDIRK3"), serial_saved, serial_path, parallel),
        (_Heat("ESDIRK3", MPI.COMM_SELF), parallel_saved, parallel_path, serial),
    ):
        reader.ts.read_checkpoint(path)
        restored = _sorted_levels(reader, reader.levels())
        for (t, x, values, slope), (t2, x2, values2, slope2) in zip(saved, restored, strict=True):
            assert t == t2
            np.testing.assert_allclose(x2, x, rtol=0, atol=1e-14)
            np.testing.assert_array_equal(values2, values)
            np.testing.assert_array_equal(slope2[0], slope[0])
            np.testing.assert_array_equal(slope2[1], slope[1])
        reader.run(STEPS - AT)
        gap = np.abs(_sorted(reader.V, reader.final) - _sorted(whole.V, whole.final)).max()
        assert gap < 1e-12, gap


@pytest.mark.mpi
def test_checkpoint_opens_as_vtkhdf(mpi_tmp_path):
    """DOLFINx reads the file's mesh back (the current nodes of the whole background), and
    its point data ``u`` are the solution at the nodes, NaN where no active cell holds the
    node, at the time of the solution."""
    path = mpi_tmp_path / "heat.vtkhdf"
    heat = _Heat("BDF2")
    heat.start()
    heat.run(2)
    heat.ts.write_checkpoint(path)
    mesh = vtkhdf.read_mesh(comm, str(path), gdim=2)
    md = heat.md
    x = md.mesh.geometry.x
    nodes = md.mesh.geometry.index_map()
    assert mesh.geometry.index_map().size_global == nodes.size_global
    assert mesh.topology.index_map(2).size_global == md.mesh.topology.index_map(2).size_global

    def everywhere(points):
        points = np.concatenate(comm.allgather(points))
        return points[np.lexsort(points.T[::-1])]

    np.testing.assert_array_equal(
        everywhere(mesh.geometry.x[: mesh.geometry.index_map().size_local]),
        everywhere(x[: nodes.size_local]),
    )
    # P2 on the degree-2 geometry: a dof at each node, the dof list of the node's cells
    node = np.empty(len(x), dtype=np.int64)
    node[heat.V.dofmap.list] = md.mesh.geometry.dofmaps[0]
    want = np.empty(len(x))
    want[node] = heat.uh.x.array
    inside = np.zeros(len(x))
    inside[md.mesh.geometry.dofmaps[0][md.active_cells]] = 1.0
    want[vertex_reduce(nodes, inside, "max") == 0.0] = np.nan  # other ranks' cells counted
    viewer = PETSc.ViewerHDF5().create(str(path), "r", comm=comm)
    for group, name, size in (
        ("/VTKHDF/PointData", "u", nodes.size_local),
        ("/VTKHDF/Steps", "Values", None),
    ):
        viewer.pushGroup(group)
        vec = (
            PETSc.Vec().createMPI((size, PETSc.DETERMINE), comm=comm)
            if size is not None
            else PETSc.Vec().create(comm)
        )
        vec.setName(name)
        vec.load(viewer)
        viewer.popGroup()
        if name == "u":
            np.testing.assert_array_equal(vec.getArray(), want[: nodes.size_local])
            assert np.isfinite(vec.getArray()).any() and np.isnan(vec.getArray()).any()
        else:
            assert vec.getSize() == 1 and comm.allreduce(vec.getArray().sum()) == heat.ts.time
    viewer.destroy()


@pytest.mark.mpi
def test_bad_checkpoints_raise_on_every_rank(mpi_tmp_path):
    """A missing file, a file that is no HDF5, a VTKHDF file without the state, a
    checkpoint of another scheme or of another space: a clear error on every rank (a
    rank left behind would hang the next collective call)."""
    good, plain, text = (mpi_tmp_path / name for name in ("good.vtkhdf", "plain.vtkhdf", "x.txt"))
    heat = _Heat("BDF2", degree=1)
    with pytest.raises(RuntimeError, match="initialize"):
        heat.ts.write_checkpoint(good)
    heat.start()
    heat.ts.write_checkpoint(good)
    vtkhdf.write_mesh(str(plain), heat.md.mesh)
    if comm.rank == 0:
        text.write_text("no HDF5\n")
    comm.barrier()
    with pytest.raises(FileNotFoundError, match="no checkpoint file"):
        _Heat("BDF2", degree=1).ts.read_checkpoint(mpi_tmp_path / "missing.vtkhdf")
    with pytest.raises(ValueError, match="no HDF5 file"):
        _Heat("BDF2", degree=1).ts.read_checkpoint(text)
    with pytest.raises(ValueError, match="holds no complete TimeStepper checkpoint"):
        _Heat("BDF2", degree=1).ts.read_checkpoint(plain)
    with pytest.raises(ValueError, match="written by a BDF2 stepper, this one is BDF3"):
        _Heat("BDF3", degree=1).ts.read_checkpoint(good)
    with pytest.raises(ValueError, match="dof values"):
        _Heat("BDF2", degree=2).ts.read_checkpoint(good)
    heat.ts.read_checkpoint(good)  # the right stepper reads it


@pytest.mark.mpi
@needs_ranks(2)
def test_redistributed_background_is_refused_on_another_number_of_ranks(mpi_tmp_path):
    """io.redistribute numbers the cells by the partition it starts from: a checkpoint
    of a serial run does not fit such a background on several ranks, which the nodes of
    the background stored in the file reveal (instead of values put at the wrong dofs)."""
    path = mpi_tmp_path / "serial.vtkhdf"
    if comm.rank == 0:
        heat = _Heat("BDF2", MPI.COMM_SELF, degree=1)
        heat.start()
        heat.ts.write_checkpoint(path)
    comm.barrier()
    bg = du.io.redistribute(du.equilateral_mesh(comm, [[-1.0, -0.9], [1.0, 1.0]], 0.1))[0]
    md = du.MovingDomain(bg, degree=1)
    md.update(_ellipse(0.0))
    ts = TimeStepper(md, fem.functionspace(md.mesh, ("Lagrange", 1)), _ellipse, 0.0, 0.05)
    with pytest.raises(ValueError, match="numbered otherwise"):
        ts.read_checkpoint(path)


def _spaces(mesh) -> dict[str, fem.FunctionSpace]:
    cell = mesh.basix_cell()
    p3, p2 = (basix.ufl.element("Lagrange", cell, k) for k in (3, 2))
    return {
        "P3": fem.functionspace(mesh, p3),
        "P3 vector": fem.functionspace(mesh, ("Lagrange", 3, (2,))),
        "P3 vector-P2 mixed": fem.functionspace(
            mesh, basix.ufl.mixed_element([basix.ufl.blocked_element(p3, (2,)), p2])
        ),
    }


def _places(V: fem.FunctionSpace) -> np.ndarray:
    """For each entry of ``Function.x.array``: its point and its component, ``(n, 4)``."""
    if V.ufl_element().is_mixed:
        out = np.empty((V.dofmap.index_map.size_local + V.dofmap.index_map.num_ghosts, 4))
        for i in range(V.num_sub_spaces):
            S, dofs = V.sub(i).collapse()
            out[np.asarray(dofs)] = _places(S) + [0.0, 0.0, 0.0, 10.0 * i]
        return out
    bs = V.dofmap.index_map_bs
    points = np.repeat(V.tabulate_dof_coordinates(), bs, axis=0)
    return np.column_stack([points, np.tile(np.arange(bs), len(points) // bs)])


@pytest.mark.mpi
@needs_ranks(2)
def test_dof_keys_do_not_depend_on_the_ranks():
    """The key of a dof names the same point and component in serial and on all ranks,
    for the edge dofs of P3 too (two per edge: DOLFINx orders a cell's dof list as the
    reference element's, whatever the global orientation of the edge), blocked and mixed
    spaces alike; the keys of a space are distinct."""
    serial = _spaces(_domain(MPI.COMM_SELF, 3).mesh)
    for name, V in _spaces(_domain(comm, 3).mesh).items():
        keys = dof_keys(serial[name])
        assert len(np.unique(keys)) == len(keys), name
        want = _places(serial[name])[np.argsort(keys)]
        got = np.column_stack([_sorted(V, column) for column in _places(V).T])
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-13, err_msg=name)


def _taylor_hood(md: du.MovingDomain) -> fem.FunctionSpace:
    cell = md.mesh.basix_cell()
    p2, p1 = (basix.ufl.element("Lagrange", cell, k) for k in (2, 1))
    return fem.functionspace(
        md.mesh, basix.ufl.mixed_element([basix.ufl.blocked_element(p2, (2,)), p1])
    )


@pytest.mark.mpi
def test_mixed_space_round_trip(mpi_tmp_path):
    """A Taylor–Hood stepper (a mixed space, with a slope from the initial time
    derivative) writes and reads its state; the file's point data hold the velocity and
    the pressure side by side."""
    path = str(mpi_tmp_path / "mixed.vtkhdf")
    md = _domain(comm)
    W = _taylor_hood(md)
    ts = TimeStepper(md, W, _ellipse, 0.0, 0.05, "BDF2")
    u0, dudt = fem.Function(W), fem.Function(W)
    u0.sub(0).interpolate(lambda x: np.stack([x[1], -x[0]]))
    u0.sub(1).interpolate(lambda x: x[0] * x[1])
    dudt.sub(1).interpolate(lambda x: 1.0 + x[0])
    for f in (u0, dudt):  # ghosts as their owners (a checkpoint stores the owners' values)
        f.x.scatter_forward()
    ts.initialize(u0, dudt)
    ts.write_checkpoint(path)
    md_again = _domain(comm)
    again = TimeStepper(md_again, _taylor_hood(md_again), _ellipse, 0.0, 0.05, "BDF2")
    u = again.read_checkpoint(path)
    np.testing.assert_array_equal(u.x.array, u0.x.array)
    (level,) = again._levels
    assert level.slope is not None
    np.testing.assert_array_equal(level.slope[0], dudt.x.array)
    np.testing.assert_array_equal(level.slope[1], 0.0)
    viewer = PETSc.ViewerHDF5().create(path, "r", comm=comm)
    viewer.pushGroup("/VTKHDF/PointData")
    vec = PETSc.Vec().create(comm)
    vec.setName("u")
    vec.load(viewer)
    viewer.destroy()
    assert vec.getSize() == 3 * md.mesh.geometry.index_map().size_global  # u_x, u_y, p
