"""User callbacks evaluated on each rank's own points raise on every rank when they fail on
one: a constraint's value, a Stokes wall or body velocity, the boundary's projection onto
its dof coordinates. The failure is on the last rank only (on one rank: that rank); before,
that rank raised alone and the others waited in the next collective call (a hang).
"""

from __future__ import annotations

from mpi4py import MPI

import numpy as np
import pytest
from dolfinx import fem

import dolfinx_universal as du
from dolfinx_universal.core.collective import MeshingError

comm = MPI.COMM_WORLD
LAST = comm.rank == comm.size - 1


def _curved():
    cm = du.conform(du.equilateral_mesh(comm, [[-1, -1], [1, 1]], 0.2), du.Circle((0, 0), 0.5))
    return du.curved_mesh(cm, 2)


def _moving():
    md = du.MovingDomain(du.equilateral_mesh(comm, [[-1, -1], [1, 1]], 0.2), degree=2)
    md.update(du.Circle((0, 0), 0.4))
    return md


def _failing(message, shape):
    def value(x):
        if LAST:
            raise ValueError(message)
        return np.zeros(shape(x))

    return value


@pytest.mark.mpi
def test_constraint_value_failing_on_one_rank():
    curved = _curved()
    V = fem.functionspace(curved.mesh, ("Lagrange", 2, (2,)))
    value = _failing("no value here", lambda x: len(x))
    with pytest.raises(RuntimeError, match="the constraint's value failed: ValueError: no value"):
        du.SlipConstraint(V, curved, value=value)


@pytest.mark.mpi
def test_stokes_velocities_failing_on_one_rank():
    md = _moving()
    wall = _failing("no wall velocity here", lambda x: (2, x.shape[1]))
    with pytest.raises(RuntimeError, match="the velocity failed: ValueError: no wall velocity"):
        du.MovingStokes(md, 1.0, (-1.0, -1.0), wall_velocity=wall)
    stokes = du.MovingStokes(md, 1.0, (-1.0, -1.0))
    body = _failing("no body velocity here", lambda x: (2, x.shape[1]))
    with pytest.raises(RuntimeError, match="the velocity failed: ValueError: no body velocity"):
        stokes.solve(body)


class _Flaky(du.Circle):
    """A circle whose projection fails on the last rank once switched on (after meshing), as
    an implicit curve's Newton projection raises where it does not converge."""

    fail = False

    def closest_point(self, x):
        if self.fail and LAST:
            raise ValueError("no closest point here")
        return super().closest_point(x)


@pytest.mark.mpi
def test_boundary_projection_failing_on_one_rank():
    flaky = _Flaky((0, 0), 0.5)
    curved = du.curved_mesh(
        du.conform(du.equilateral_mesh(comm, [[-1, -1], [1, 1]], 0.2), flaky), 2
    )
    V = fem.functionspace(curved.mesh, ("Lagrange", 2, (2,)))
    flaky.fail = True
    match = "closest-point projection failed: ValueError: no closest point"
    with pytest.raises(MeshingError, match=match):
        du.boundary_dof_data(V, curved)
    with pytest.raises(MeshingError, match=match):
        du.SlipConstraint(V, curved)
