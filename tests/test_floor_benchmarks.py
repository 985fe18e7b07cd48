"""The floor benchmarks run (``--quick``) and print their ratio tables; no timing asserts."""

from __future__ import annotations

import re

import pytest
from conftest import ROOT, run_mpi

SCRIPTS = {
    "update_floor.py": 4,  # with and without the relaxation
    "conform_floor.py": 2,
    "curved_floor.py": 4,
}
"""Benchmark -> number of table rows it prints."""


@pytest.mark.skip_in_parallel
@pytest.mark.parametrize("script", sorted(SCRIPTS))
def test_floor_benchmark_quick(script):
    out = run_mpi(1, [str(ROOT / "benchmarks" / script), "--quick"], timeout=600).stdout
    rows = re.findall(r"^\| (.+?) +\| +([\d.]+)ms \| +([\d.]+)ms \| +([\d.]+)x \|$", out, re.M)
    assert len(rows) == SCRIPTS[script], out
    for name, package, floor, ratio in rows:
        assert float(package) > 0 and float(floor) > 0, (name, out)
        assert abs(float(ratio) - float(package) / float(floor)) < 0.01 * float(ratio) + 0.01
    assert out.count("ratios: ") == 1, out
    if script == "update_floor.py":
        assert re.search(r"relaxation share .*equilateral: \d+ %, propeller graded: \d+ %", out)
