"""The disc-on-a-spring demo: quick mode in serial and on two ranks, same trajectory."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import run_mpi

KEYS = {
    "dt",
    "steps",
    "trajectory",
    "final_position",
    "final_speed",
    "spring_force_final",
    "fluid_force_final",
}
WRITTEN = {"parameters", "reference", "versions", "mpi_size"}  # demo_support.write_summary


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[int, tuple[dict, dict]]:
    """``{nprocs: (summary, forces)}`` of ``--quick`` runs on 1 and 2 ranks."""
    out = {}
    for nprocs in (1, 2):
        folder = tmp_path_factory.mktemp(f"disc{nprocs}")
        run_mpi(
            nprocs, ["demos/stokes_disc_spring.py", "--quick", "--out", str(folder)], timeout=300
        )
        out[nprocs] = tuple(
            json.loads((folder / name).read_text()) for name in ("summary.json", "forces.json")
        )
        if nprocs == 1:
            for name in ("trajectory.png", "frames.png", "settling.png"):
                assert (folder / name).stat().st_size > 10_000
    return out


def test_summary(runs):
    summary, forces = runs[1]
    assert set(summary) == KEYS | WRITTEN
    assert len(summary["reference"]["equilibrium_position"]) == 2
    assert summary["dt"] == 0.05 and summary["steps"] == 20
    traj = np.array(summary["trajectory"])
    assert traj.shape == (21, 3)
    assert np.allclose(traj[:, 0], 0.05 * np.arange(21))
    assert traj[0, 1:] == pytest.approx([0.25, 0.25])
    assert summary["final_position"] == traj[-1, 1:].tolist()
    # The restoring spring: -k (1 - l0/|c|) c with k = 1, l0 = 1/4.
    c = np.array(summary["final_position"])
    assert summary["spring_force_final"] == pytest.approx(  # the same formula: ulps
        -(1 - 0.25 / np.linalg.norm(c)) * c, rel=1e-12
    )
    assert summary["fluid_force_final"] == forces["steps"][-1]["F_var"]


def test_serial_equals_parallel(runs):
    (s1, f1), (s2, f2) = runs[1], runs[2]
    assert s1["steps"] == s2["steps"]
    # The same meshes; the solvers' rounding differs with the partition (measured 5e-14
    # relative in the forces); atol: a floor for components near 0.
    np.testing.assert_allclose(s1["trajectory"], s2["trajectory"], rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(
        [f["F_var"] for f in f1["steps"]], [f["F_var"] for f in f2["steps"]], rtol=1e-7, atol=1e-12
    )


def test_two_force_computations_agree(runs):
    _, forces = runs[1]
    # Surface integral and weak residual agree to the discretisation error (about 1 % on
    # the quick mode's background, h = R/3).
    for f in forces["steps"]:
        gap = np.linalg.norm(np.subtract(f["F_surf"], f["F_var"]))
        assert gap < 0.02 * np.linalg.norm(f["F_var"]), f
    # The convergence study: both converge, the weak residual faster and with smaller
    # differences on every level (order about 4 against 2 to 3).
    study = forces["study"]
    assert [s["level"] for s in study] == [0, 1, 2]
    diffs = {
        key: np.linalg.norm(np.diff([s[key] for s in study], axis=0), axis=1)
        for key in ("F_surf", "F_var")
    }
    assert np.all(diffs["F_var"] < diffs["F_surf"])
    assert diffs["F_var"][0] / diffs["F_var"][1] > 8  # order > 3
    assert diffs["F_var"][1] < 1e-4 * np.linalg.norm(study[-1]["F_var"])
    gaps = [np.linalg.norm(np.subtract(s["F_surf"], s["F_var"])) for s in study]
    assert gaps[2] < gaps[1] < gaps[0]


def test_dynamics(runs):
    summary, forces = runs[1]
    traj = np.array(summary["trajectory"])
    steps = forces["steps"]
    dt = summary["dt"]
    # The first step from rest: c^1 = c^0 + dt^2/2 (F_s + F_f)(c^0), m = 1.
    accel = np.add(steps[0]["F_spring"], steps[0]["F_var"])
    assert traj[1, 1:] == pytest.approx(traj[0, 1:] + 0.5 * dt**2 * accel, rel=1e-12)  # ulps
    # Central differences: c^{n+1} - 2 c^n + c^{n-1} = dt^2 (F_s + F_f)(c^n).
    for n in range(1, len(traj) - 1):
        accel = np.add(steps[n]["F_spring"], steps[n]["F_var"])
        second = traj[n + 1, 1:] - 2 * traj[n, 1:] + traj[n - 1, 1:]
        # rounding of positions ~0.3: 4e-17 measured, against dt^2 |a| >= 1e-4 here
        assert second == pytest.approx(dt**2 * accel, rel=1e-9, abs=1e-15)
    # The flow drags the disc downstream (x grows); the spring pulls it towards the
    # centreline (y falls); the drag at rest, downstream, exceeds the drag on the moving disc.
    assert np.all(np.diff(traj[:, 1]) > 0) and np.all(np.diff(traj[:, 2]) < 0)
    assert steps[0]["F_var"][0] > 0 and steps[-1]["F_var"][0] < steps[0]["F_var"][0]
    # Energy bounded: kinetic + spring energy never exceeds its start plus the work of the
    # largest fluid force along the path.
    c = traj[:, 1:]
    v = np.diff(c, axis=0) / dt
    spring = 0.5 * (np.linalg.norm(c[1:], axis=1) - 0.25) ** 2
    energy = 0.5 * (v**2).sum(axis=1) + spring
    path = np.cumsum(np.linalg.norm(np.diff(c, axis=0), axis=1))
    f_max = max(np.linalg.norm(f["F_var"]) for f in steps)
    assert np.all(energy <= 0.5 * (np.linalg.norm(c[0]) - 0.25) ** 2 + f_max * path + 1e-12)
    assert summary["final_speed"] == pytest.approx(
        np.linalg.norm(traj[-1, 1:] - traj[-2, 1:]) / dt, rel=0.2
    )
