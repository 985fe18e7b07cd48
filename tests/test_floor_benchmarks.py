"""The floor benchmarks run (``--quick``) and print their ratio tables; no timing asserts.

Also the 3D comparison with gmsh (``conform_vs_gmsh_3d.py --quick``, skipped without gmsh):
its tables and JSON, and the quality it reports (no timing asserts either).
"""

from __future__ import annotations

import importlib.util
import json
import re

import pytest
from conftest import ROOT, run_mpi

SCRIPTS = {
    "update_floor.py": 4,  # with and without the relaxation
    "conform_floor.py": 2,
    "curved_floor.py": 4,
    "conform_floor_3d.py": 6,  # ball and torus: conform, without create_submesh, relaxed
    "curved_floor_3d.py": 8,  # ball and torus: curved_mesh q=2, 3; update, less relaxation
}
"""Benchmark -> number of table rows it prints."""
TABLES = {"curved_floor_3d.py": 2}
"""Benchmarks printing more than one table."""


@pytest.mark.skip_in_parallel
@pytest.mark.parametrize("script", sorted(SCRIPTS))
def test_floor_benchmark_quick(script):
    out = run_mpi(1, [str(ROOT / "benchmarks" / script), "--quick"], timeout=600).stdout
    rows = re.findall(r"^\| (.+?) +\| +([\d.]+)ms \| +([\d.]+)ms \| +([\d.]+)x \|$", out, re.M)
    assert len(rows) == SCRIPTS[script], out
    for name, package, floor, ratio in rows:
        assert float(package) > 0 and float(floor) > 0, (name, out)
        assert abs(float(ratio) - float(package) / float(floor)) < 0.01 * float(ratio) + 0.01
    assert out.count("ratios: ") == TABLES.get(script, 1), out
    if script == "update_floor.py":
        assert re.search(r"relaxation share .*equilateral: \d+ %, propeller graded: \d+ %", out)
    if script == "curved_floor_3d.py":
        assert re.search(r"relaxation share .*ball r=0.8: \d+ %, torus R=0.55 r=0.3: \d+ %", out)
    if script == "conform_floor_3d.py":
        assert re.search(r"relaxation share .*ball r=0.8: \d+ %, torus R=0.55 r=0.3: \d+ %", out)
        # the floor builds the package's relax=False mesh (same kept cells and vertices)
        assert out.count("the same as the floor's: True; largest vertex difference") == 2, out


@pytest.mark.skip_in_parallel
@pytest.mark.skipif(importlib.util.find_spec("gmsh") is None, reason="gmsh not installed")
def test_conform_vs_gmsh_3d_quick(tmp_path):
    out_json = tmp_path / "ball.json"
    script = str(ROOT / "benchmarks" / "conform_vs_gmsh_3d.py")
    out = run_mpi(1, [script, "--quick", "--out", str(out_json)], timeout=600).stdout
    assert "Mesh the unit ball" in out and "dihedral angle histogram" in out, out
    (row,) = json.loads(out_json.read_text())["rows"]
    assert row["universal_total_s"] > row["conform_s"] > 0 and row["gmsh_total_s"] > 0
    uq, gq = row["universal_quality"], row["gmsh_quality"]
    # comparable sizes: gmsh's size is calibrated on the universal mesh's count
    assert 0.7 < gq["n_cells"] / uq["n_cells"] < 1.4, (uq["n_cells"], gq["n_cells"])
    for q in (uq, gq):
        assert q["n_inverted"] == 0 and sum(q["dihedral_histogram"]) == 6 * q["n_cells"]
    # the universal mesh's dihedral angles are better at both ends
    assert uq["theta_min_deg"] > gq["theta_min_deg"] and uq["theta_max_deg"] < gq["theta_max_deg"]


def test_timed_pairs_interleaves_or_times_apart():
    """``timed_pairs`` calls the functions step by step, or (``apart``) one after the other."""
    import sys

    from mpi4py import MPI

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _floor import timed_pairs

    calls: list[tuple[str, int]] = []
    fns = {key: (lambda step, key=key: calls.append((key, step))) for key in ("a", "b")}
    times = timed_pairs(MPI.COMM_SELF, fns, 2)
    assert calls == [("a", 0), ("b", 0), ("a", 1), ("b", 1), ("a", 2), ("b", 2)]
    assert set(times) == {"a", "b"} and min(times.values()) >= 0
    calls.clear()
    timed_pairs(MPI.COMM_SELF, fns, 2, apart=True)
    assert calls == [("a", 0), ("a", 1), ("a", 2), ("b", 0), ("b", 1), ("b", 2)]
