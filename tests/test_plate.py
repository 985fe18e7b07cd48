"""The Reissner-Mindlin plate demo, quick mode, in serial and on two ranks."""

from __future__ import annotations

import json

from mpi4py import MPI

import numpy as np
import pytest
from conftest import ROOT, run_mpi

if MPI.COMM_WORLD.size > 1:
    pytest.skip("runs the demo with its own mpirun", allow_module_level=True)

VARIANTS = ("I_true_tangent", "G_true_tangent", "I_discrete_tangent")
W_EXACT = 17 * 1e-3 * 3.142  # p (R^4 + R^2 tau^2) / (4 tau^3) with tau = R/4


@pytest.fixture(scope="module")
def summaries(tmp_path_factory):
    out = {}
    for n in (1, 2):
        folder = tmp_path_factory.mktemp(f"plate{n}")
        run_mpi(n, [str(ROOT / "demos" / "plate.py"), "--quick", "--out", str(folder)])
        out[n] = json.loads((folder / "summary.json").read_text())
        assert (folder / "deflection.png").stat().st_size > 0
        assert (folder / "w_center.png").stat().st_size > 0
    return out


def table(summary: dict) -> dict[str, np.ndarray]:
    return {
        v: np.array([r["w_center"] for r in summary["rows"] if r["variant"] == v]) for v in VARIANTS
    }


def test_summary_format(summaries):
    for summary in summaries.values():
        assert list(summary) == ["rows", "parameters", "reference", "versions", "mpi_size"]
        assert summary["parameters"]["quick"] is True and summary["parameters"]["R"] == 3.142
        # a closed formula of a few operations: ulps
        assert summary["reference"]["w_center_exact"] == pytest.approx(W_EXACT, rel=1e-12)
        assert len(summary["rows"]) == 2 * len(VARIANTS)
        for row in summary["rows"]:
            assert set(row) == {"variant", "level", "h", "n_dofs", "w_center"}
            assert row["variant"] in VARIANTS and row["level"] in (0, 1)
            assert isinstance(row["n_dofs"], int) and isinstance(row["w_center"], float)


@pytest.mark.mpi
def test_serial_and_parallel_agree(summaries):
    assert (summaries[1]["mpi_size"], summaries[2]["mpi_size"]) == (1, 2)
    assert summaries[1]["parameters"] == summaries[2]["parameters"]
    for a, b in zip(summaries[1]["rows"], summaries[2]["rows"]):
        assert (a["variant"], a["level"], a["n_dofs"]) == (b["variant"], b["level"], b["n_dofs"])
        assert abs(a["w_center"] - b["w_center"]) < 1e-8 * abs(a["w_center"])


def test_true_tangent_right_discrete_tangent_wrong(summaries):
    w = table(summaries[1])
    spread = np.abs(w["I_true_tangent"] - w["G_true_tangent"])
    miss = np.abs(w["I_discrete_tangent"] - w["I_true_tangent"])
    assert np.all(miss > 100 * spread)
    for v in ("I_true_tangent", "G_true_tangent"):
        err = np.abs(w[v] - W_EXACT)
        assert err[1] < 0.2 * err[0] and err[1] < 1e-4 * W_EXACT
    # The discrete tangent clamps the boundary vertices: the plate gets stiffer with h.
    assert np.all(np.diff(w["I_discrete_tangent"]) < 0)
    assert np.all(w["I_discrete_tangent"] < 0.5 * W_EXACT)
