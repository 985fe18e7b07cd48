"""The Lamé thick-sphere elasticity demo (quick mode) in serial and on two ranks."""

from __future__ import annotations

import pytest
from conftest import quick_runs
from test_demos import SUMMARY_KEYS, _same_run, _without_seconds

ROW_KEYS = {
    "k",
    "q",
    "h",
    "n_cells",
    "dofs",
    "boundary_dof_distance",
    "L2",
    "H1",
    "solver",
    "iterations",
    "seconds",
}
FIGURES = ("convergence.png", "shell_mesh.png")


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict:
    """``{nprocs: (out folder, summary)}`` for one serial and one two-rank quick run."""
    return quick_runs(tmp_path_factory, "elasticity_3d.py")


@pytest.mark.skip_in_parallel  # runs the demo under its own mpirun
def test_summary_and_outputs(runs):
    for out, summary in runs.values():
        assert {"rows", "rates", "seconds"} | SUMMARY_KEYS == summary.keys()
        p = summary["parameters"]
        assert p["quick"] is True and p["h"] == [0.4, 0.2]
        assert p["mesh_domain"]["tet_background"] == "a15"
        rows = summary["rows"]
        assert len(rows) == 6 and all(set(r) == ROW_KEYS for r in rows)
        assert set(rows[0]["seconds"]) == {"mesh", "solve", "errors"}
        assert {(r["k"], r["q"]) for r in rows} == {(2, 1), (2, 2), (2, 3)}
        for h in (0.4, 0.2):  # one straight conforming mesh under the three geometries
            at = [r for r in rows if r["h"] == h]
            assert len({(r["n_cells"], r["dofs"]) for r in at}) == 1, at
        assert all(r["solver"] == "MUMPS" for r in rows)
        assert {(r["k"], r["q"]) for r in summary["rates"]} == {(2, 1), (2, 2), (2, 3)}
        for name in FIGURES:
            assert (out / name).stat().st_size > 10_000


@pytest.mark.skip_in_parallel  # runs the demo under its own mpirun
def test_closed_form(runs):
    """Lamé's constants, recomputed here, meet sigma_rr(a) = -p and sigma_rr(b) = 0."""
    _, summary = runs[1]
    m, ref = summary["parameters"]["material"], summary["reference"]
    E, nu, p = m["E"], m["nu"], summary["parameters"]["pressure"]
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    assert (m["lambda"], m["mu"]) == pytest.approx((lam, mu), rel=1e-14)
    a, b = 0.5, 1.0
    A, B = ref["A"], ref["B"]

    def sigma_rr(r):
        return (3 * lam + 2 * mu) * A - 4 * mu * B / r**3

    assert sigma_rr(a) == pytest.approx(-p, rel=1e-13)
    assert sigma_rr(b) == pytest.approx(0.0, abs=1e-13)
    # The demo's own finite-difference check of the closed form (tractions, equilibrium).
    assert set(ref["closed_form_residuals"]) == {"inner_traction", "outer_traction", "equilibrium"}
    assert max(ref["closed_form_residuals"].values()) < 1e-6


@pytest.mark.skip_in_parallel  # runs the demo under its own mpirun
def test_errors_and_rates(runs):
    _, summary = runs[1]
    rows = summary["rows"]
    for h in (0.4, 0.2):
        at = {r["q"]: r for r in rows if r["h"] == h}
        # The curved boundary: P2 nodes on the outer sphere for q = 2, within O(h^4) for
        # q = 3, O(h^2) inside on the straight mesh.
        assert at[2]["boundary_dof_distance"] < 1e-12
        assert 1e-9 < at[3]["boundary_dof_distance"] < 0.02 * h**4
        assert 0.05 * h**2 < at[1]["boundary_dof_distance"] < 0.25 * h**2
        for q in (2, 3):  # the curved meshes: much smaller errors than the straight one
            assert at[q]["L2"] < 0.2 * at[1]["L2"] and at[q]["H1"] < at[1]["H1"], (h, q)
    for r in summary["rates"]:
        # Coarse (pre-asymptotic) quick sizes: the rates are only roughly optimal.
        if r["q"] > 1:
            assert r["L2_rate"] > 1.8 and r["H1_rate"] > 1.1, r
        assert r["L2_rates"] == [r["L2_rate"]] and r["H1_rates"] == [r["H1_rate"]]


@pytest.mark.skip_in_parallel  # runs the demo under its own mpirun
def test_serial_equals_parallel(runs):
    # The same meshes on 2 ranks, the same discrete problems (MUMPS): the same errors up to
    # the solver's rounding (measured: 1e-14 relative); times differ and are left out.
    (_, serial), (_, parallel) = runs[1], runs[2]
    _same_run(_without_seconds(serial), _without_seconds(parallel), rtol=1e-9)
