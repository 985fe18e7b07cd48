"""The oscillating sphere (demo, quick mode: three BDF steps on an A15 background of size
0.1) in serial and on three ranks."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import ROOT, run_mpi

DEMO = ROOT / "demos" / "oscillating_sphere_3d.py"
RANKS = (1, 3)  # three: an odd partition of the redistributed background


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict:
    """``{nprocs: (out folder, summary)}`` of the quick demo on one and three ranks."""
    result = {}
    for nprocs in RANKS:
        out = tmp_path_factory.mktemp(f"oscillating_sphere_3d_np{nprocs}")
        run_mpi(nprocs, [str(DEMO), "--quick", "--out", str(out)], timeout=300)
        result[nprocs] = out, json.loads((out / "summary.json").read_text())
    return result


@pytest.mark.skip_in_parallel  # runs the demo under its own mpirun
def test_summary_and_forces(runs):
    """The keys outside checks read, one value per step; the fluid resists the sphere's
    start to the right: C_D < 0 at every step (measured -18.5 at the first, the added mass
    times the velocity's jump over dt, then -5.3 and -3.1). The transverse force, zero for
    the axisymmetric exact flow, is below 1 % of the drag's magnitude at every step
    (measured at most 0.12 %: 6.0e-3 against 5.3; the full run's largest is 0.15 % where
    |C_D| > 1). Every curved tetrahedron is valid; the fluid is a part of the background."""
    for nprocs, (out, summary) in runs.items():
        assert summary["mpi_size"] == nprocs
        params = summary["parameters"]
        assert params["ranks"] == nprocs and params["quick"]
        t, c_D, c_L = (np.array(summary[k]) for k in ("t", "c_D", "c_L"))
        steps = round(params["t_end"] / params["dt"])
        for key in ("c_D", "c_L", "c_y", "c_z"):
            assert len(summary[key]) == steps == 3, key
        assert np.isclose(t[-1], params["t_end"])
        assert np.all(c_D < 0)
        assert np.all(c_L < 0.01 * np.abs(c_D))
        assert np.allclose(c_L, np.hypot(summary["c_y"], summary["c_z"]))
        assert summary["c_D_range"][1] < 0 and summary["c_T_max"] <= c_L.max()
        assert summary["min_jacobian_ratio"] > 0
        assert 0 < summary["n_active_cells"] < summary["n_cells"]
        assert summary["n_dofs"] > 0 and summary["seconds_per_step"] > 0
        assert 0 < summary["moving_share"] < 1
        for name in ("forces.png", "flow.png"):
            assert (out / name).stat().st_size > 10_000


@pytest.mark.skip_in_parallel
def test_same_forces_on_three_ranks(runs):
    """The same background (A15, built in layers and redistributed), the same conformed
    meshes and so the same coefficients on one and three ranks, to the rounding of the
    solves: atol 1e-6 of the first step's |C_D| (18.5), measured 4e-14."""
    one, three = runs[1][1], runs[3][1]
    assert one["n_cells"] == three["n_cells"] and one["n_dofs"] == three["n_dofs"]
    assert one["min_jacobian_ratio"] == pytest.approx(three["min_jacobian_ratio"], rel=1e-12)
    atol = 1e-6 * abs(one["c_D"][0])
    for key in ("c_D", "c_y", "c_z"):
        np.testing.assert_allclose(one[key], three[key], rtol=0, atol=atol, err_msg=key)
