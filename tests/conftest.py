"""Shared fixtures: MPI-safe temporary directories, MPI markers, a runner for demo scripts.

MPI tests are marked ``mpi`` and run in-process on every rank: ``.ci/test`` runs
``mpirun -n 2`` and ``-n 3 python -m pytest -m mpi`` (tests marked ``skip_in_parallel`` skip
there). Demos are run as scripts, serially and under mpirun, by :func:`run_mpi` (as DOLFINx's
own demo tests do).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import dolfinx_universal  # noqa: F401  (initialises the DOLFINx wheel before dolfinx imports)

ROOT = Path(__file__).resolve().parents[1]


def pytest_configure(config):
    config.addinivalue_line(
        "markers",
        "skip_in_parallel: serial-only test (skipped when pytest itself runs under mpirun)",
    )


def pytest_collection_modifyitems(config, items):
    from mpi4py import MPI

    if MPI.COMM_WORLD.size == 1:
        return
    skip = pytest.mark.skip(reason="serial-only test (running under mpirun)")
    for item in items:
        if "skip_in_parallel" in item.keywords:
            item.add_marker(skip)


def needs_ranks(n: int = 2):
    """Skip unless pytest runs on at least ``n`` ranks (``mpirun -n N python -m pytest -m mpi``)."""
    from mpi4py import MPI

    return pytest.mark.skipif(
        MPI.COMM_WORLD.size < n, reason=f"needs mpirun with >= {n} ranks (see .ci/test)"
    )


def mpirun() -> str | None:
    """The mpirun that belongs to this Python (the mpich wheel's), else the one on PATH."""
    local = Path(sys.executable).parent / "mpirun"
    return str(local) if local.exists() else shutil.which("mpirun")


def run_mpi(nprocs: int, args: list[str], timeout: float = 300) -> subprocess.CompletedProcess:
    """Run ``python args...`` on ``nprocs`` ranks (plain python when ``nprocs == 1``)."""
    cmd = [sys.executable, *args]
    if nprocs > 1:
        exe = mpirun()
        if exe is None:
            pytest.skip("mpirun not found")
        cmd = [exe, "-n", str(nprocs), *cmd]
    env = dict(os.environ, OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    # Open MPI (some DOLFINx images) refuses to run as root without these.
    env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        raise AssertionError(
            f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n"
            f"{proc.stderr[-5000:]}"
        )
    return proc


def quick_runs(tmp_path_factory, demo: str, timeout: float = 300) -> dict[int, tuple[Path, dict]]:
    """``{nprocs: (out folder, summary)}`` of ``demos/<demo> --quick`` run serially and on
    two ranks (a demo test's module fixture)."""
    result = {}
    for nprocs in (1, 2):
        out = tmp_path_factory.mktemp(f"{Path(demo).stem}_np{nprocs}")
        run_mpi(nprocs, [str(ROOT / "demos" / demo), "--quick", "--out", str(out)], timeout)
        result[nprocs] = out, json.loads((out / "summary.json").read_text())
    return result


def run_mpi_json(nprocs: int, script: str, out: Path, *args: str) -> dict:
    """Run ``tests/mpi/<script>`` writing JSON to ``out`` and return what it wrote."""
    run_mpi(nprocs, [str(ROOT / "tests" / "mpi" / script), str(out), *args])
    return json.loads(out.read_text())


@pytest.fixture
def mpi_tmp_path(tmp_path_factory):
    """A temporary directory shared by all ranks of this process's communicator."""
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    path = str(tmp_path_factory.mktemp("mpi")) if comm.rank == 0 else None
    return Path(comm.bcast(path, root=0))


def assert_update_history_free(background, degree: int, here, there) -> None:
    """A moving update does not depend on the previous steps: after ``here``, ``there``,
    ``here`` the geometry and the indicator equal those of a fresh ``MovingDomain`` updated
    once to ``here`` (every node of the previous step's moved cells restored)."""
    import numpy as np

    stepped = dolfinx_universal.MovingDomain(background, degree=degree)
    fresh = dolfinx_universal.MovingDomain(background, degree=degree)
    for boundary in (here, there, here):
        stepped.update(boundary)
    fresh.update(here)
    # A node shared by two rewritten cells is computed in each (affine images summed in
    # each cell's vertex order): equal up to rounding, about 1e-16 of the O(1) coordinates.
    np.testing.assert_allclose(stepped.mesh.geometry.x, fresh.mesh.geometry.x, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(stepped.active.x.array, fresh.active.x.array)
