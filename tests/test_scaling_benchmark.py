"""The strong-scaling benchmark runs under mpirun and prints its table (no timing asserts)."""

from __future__ import annotations

import pytest
from conftest import ROOT, run_mpi


@pytest.mark.skip_in_parallel
def test_scaling_benchmark_quick():
    proc = run_mpi(2, [str(ROOT / "benchmarks" / "scaling.py"), "--quick"], timeout=600)
    lines = proc.stdout.strip().splitlines()
    assert any(line.startswith("ranks: 2") for line in lines), proc.stdout
    head = next(i for i, line in enumerate(lines) if line.split()[:2] == ["cells", "max/rank"])
    assert lines[head].split()[2:] == [
        "background", "prepare", "conform", "straight", "mesh", "curved", "update"
    ]  # fmt: skip
    row = lines[head + 1].split()
    cells, max_local = int(row[0]), int(row[1])
    assert cells > 1e4 and cells / 2 <= max_local < cells  # both ranks own cells
    assert len(row) == 9 and all(float(v) > 0 for v in row[2:])
