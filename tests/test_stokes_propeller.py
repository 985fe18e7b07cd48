"""The rotating-propeller Stokes demo (quick mode) in serial and on two ranks."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import quick_runs

KEYS = {
    "steps",
    "background_cells",
    "angles_deg",
    "torque",
    "min_angle_deg",
    "max_q",
    "net_flux",
    "timing",
}
WRITTEN = {"parameters", "reference", "versions", "mpi_size"}  # demo_support.write_summary
FIGURES = ("mesh_frames.png", "flow_frames.png", "torque.png")


def mirror_gap(angles_deg, torque) -> float:
    """max |T(theta) - T(-60 - theta)| / mean T over the pairs of computed angles (mod 120)."""
    key = {round(a % 120, 6): t for a, t in zip(angles_deg, torque)}
    gaps = [abs(t - key[m]) for a, t in key.items() if (m := round((-60 - a) % 120, 6)) in key]
    assert len(gaps) >= 6
    return max(gaps) / float(np.mean(torque))


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict:
    """``{nprocs: (out folder, summary)}`` for one serial and one two-rank quick run."""
    return quick_runs(tmp_path_factory, "stokes_propeller.py")


@pytest.mark.skip_in_parallel  # runs the demo under its own mpirun
def test_summary_and_outputs(runs):
    for out, summary in runs.values():
        assert set(summary) == KEYS | WRITTEN
        assert summary["reference"]["period_deg"] == 120.0
        assert set(summary["timing"]) == {"update_s_median", "assemble_s_median", "solve_s_median"}
        assert all(isinstance(v, float) for v in summary["timing"].values())
        # A third of a revolution, clockwise, in 10 degree steps.
        assert summary["steps"] == len(summary["angles_deg"]) == len(summary["torque"]) == 13
        assert summary["angles_deg"][0] == 0 and summary["angles_deg"][-1] == -120
        assert 0 < summary["min_angle_deg"] < 60 and summary["max_q"] >= 2
        for name in FIGURES:
            assert (out / name).stat().st_size > 10_000
        assert any((out / "stokes.bp").glob("data.*"))


@pytest.mark.skip_in_parallel  # runs the demo under its own mpirun
def test_physics(runs):
    _, summary = runs[1]
    torque = np.array(summary["torque"])
    # The fluid resists the clockwise rotation: counter-clockwise (positive) torque.
    assert (torque > 0).all()
    # 0 and -120 degrees are the same propeller (threefold symmetry) on the same background.
    assert torque[-1] == pytest.approx(torque[0], rel=1e-9)
    # ... but the torque does depend on the angle (walls, shear flow).
    assert np.ptp(torque) > 0.02 * torque.mean()
    # The mirror image in the y axis of the propeller at angle theta is the propeller at
    # -60 - theta, and the mirrored flow is minus the flow of that angle: T(theta) =
    # T(-60 - theta), up to the discretisation error (the meshes are not mirror images).
    assert mirror_gap(summary["angles_deg"], torque) < 0.03
    # No net flux through the container walls (the inflow is 0.98).
    assert abs(summary["net_flux"]) < 1e-10


@pytest.mark.skip_in_parallel  # runs the demo under its own mpirun
def test_serial_equals_parallel(runs):
    (_, serial), (_, parallel) = runs[1], runs[2]
    for key in ("steps", "background_cells", "angles_deg"):
        assert serial[key] == parallel[key]
    assert parallel["torque"] == pytest.approx(serial["torque"], rel=1e-6)
    # The same meshes (relaxation decisions do not depend on the partition, TIE in relax.py):
    # equal here, but positions may differ by rounding (~1e-15), which moves angles by about
    # 1e-15 / h ~ 1e-13 (h = 0.012); a changed mesh (>= 1e-9 h) moves them by >= 1e-9.
    assert parallel["min_angle_deg"] == pytest.approx(serial["min_angle_deg"], rel=1e-10)
    assert parallel["max_q"] == pytest.approx(serial["max_q"], rel=1e-10)
