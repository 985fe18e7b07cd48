"""The heat equation on moving domains (demo, quick mode) in serial and on two ranks."""

from __future__ import annotations

import pytest
from conftest import ROOT, quick_runs

DEMO = ROOT / "demos" / "heat_moving.py"
KEYS = {"space_rates", "time_rates", "boundary_conditions", "relaxation", "space_runs",
        "time_runs", "seconds"}  # fmt: skip
WRITTEN = {"parameters", "reference", "versions", "mpi_size"}
FIGURES = ("solution.png", "space.png", "time.png")


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict:
    return quick_runs(tmp_path_factory, DEMO.name, timeout=600)


@pytest.mark.skip_in_parallel  # runs the demo under its own mpirun
def test_summary_and_outputs(runs):
    for nprocs, (out, summary) in runs.items():
        assert set(summary) == KEYS | WRITTEN and summary["mpi_size"] == nprocs
        assert summary["parameters"]["quick"] is True
        space = summary["space_rates"]
        assert {(r["dim"], r["k"]) for r in space} == {(2, 1), (2, 2), (2, 3), (3, 1), (3, 2)}
        assert all(set(r) == {"dim", "case", "k", "L2", "H1"} for r in space)
        time = summary["time_rates"]
        assert {r["integrator"] for r in time} == {"BDF1", "BDF2", "BDF3", "ESDIRK3"}
        assert all(set(r) == {"dim", "case", "integrator", "order", "rate"} for r in time)
        assert {r["bc"] for r in summary["boundary_conditions"]} == {
            "dirichlet",
            "neumann",
            "robin",
        }
        for name in FIGURES:
            assert (out / name).stat().st_size > 10_000


@pytest.mark.skip_in_parallel
def test_rates_on_the_coarse_meshes(runs):
    """Quick mode's meshes are coarse (h = 0.2, 0.1 in 2D): the L2 orders are at least
    k + 1/2 in 2D (measured 1.81, 2.87, 6.19) and every condition on Gamma converges at
    P2 (measured 2.87, 3.06, 2.91); BDF1 shows its order (0.9)."""
    _, summary = runs[1]
    for r in summary["space_rates"]:
        if r["dim"] == 2:
            assert r["L2"] > r["k"] + 0.5, r
            assert r["H1"] > r["k"] - 0.3, r
    for r in summary["boundary_conditions"]:
        assert r["L2_rate"] > 2.5, r
    bdf1 = [r for r in summary["time_rates"] if r["integrator"] == "BDF1" and r["dim"] == 2]
    assert abs(bdf1[0]["rate"] - 1.0) < 0.2


@pytest.mark.skip_in_parallel
def test_same_numbers_on_two_ranks(runs):
    """The errors of every run agree between one and two ranks to rounding (1e-8
    relative; measured 4e-11): the meshes, the paths and the carried values are the same,
    the points of entering cells taking their extensions from the same old cells on any
    number of ranks."""
    one, two = runs[1][1], runs[2][1]
    for key in ("space_runs", "time_runs"):
        for a, b in zip(one[key], two[key], strict=True):
            assert a["L2"] == pytest.approx(b["L2"], rel=1e-8)
            assert a["H1"] == pytest.approx(b["H1"], rel=1e-8)
