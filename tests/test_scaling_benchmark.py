"""The strong-scaling benchmark runs under mpirun and prints its table (no timing asserts),
and its figures of the mesh are those of a serial run."""

from __future__ import annotations

import json

import pytest
from conftest import ROOT, run_mpi

SCRIPT = str(ROOT / "benchmarks" / "scaling.py")


@pytest.mark.skip_in_parallel
@pytest.mark.parametrize("dim", [2, 3])
def test_scaling_benchmark_quick(dim, tmp_path):
    rows = {}
    for n in (1, 2):
        out = tmp_path / f"rows{n}.json"
        proc = run_mpi(n, [SCRIPT, "--quick", "--dim", str(dim), "--json", str(out)], timeout=600)
        rows[n] = json.loads(out.read_text())["rows"][0]
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
    # The same mesh on one rank and on two: equal counts; extreme angles and the proven
    # Jacobian ratio are minima and maxima over cells, equal up to the rounding of a cell's
    # figures computed from its vertices in another order (a few ulps); the sum of squared
    # coordinates adds the same terms in another order (about 1e-13 relative at 1e4 terms).
    one, two = rows[1], rows[2]
    assert one["ranks"] == 1 and two["ranks"] == 2
    for key in ("cells", "kept", "positively_cut"):
        assert one[key] == two[key], key
    for key in ("angle_min", "angle_max", "jacobian_ratio", "moment"):
        assert two[key] == pytest.approx(one[key], rel=1e-12, abs=0.0), key


@pytest.mark.skip_in_parallel
def test_scaling_benchmark_mesh_domain():
    proc = run_mpi(2, [SCRIPT, "--mesh-domain", "0.15", "--repeats", "1"], timeout=600)
    line = next(line for line in proc.stdout.splitlines() if line.startswith("ranks: 2"))
    assert "mesh_domain(torus, h=0.15, degree=2)" in line and "io.redistribute" in line, line
