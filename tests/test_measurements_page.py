"""``docs/measurements.md`` is the page that ``benchmarks/measurements_page.py`` generates from
the committed results in ``benchmarks/results/``: regenerated in memory, it must be identical
(the page never drifts from the JSON). The README's numbers about gmsh are on that page."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import measurements_page  # noqa: E402


def test_page_is_generated_from_the_results():
    page = (ROOT / "docs" / "measurements.md").read_text()
    assert page == measurements_page.page(), "run: python benchmarks/measurements_page.py"


def test_every_result_has_the_common_header():
    files = sorted((ROOT / "benchmarks" / "results").glob("*.json"))
    assert files
    for path in files:
        run = json.loads(path.read_text())["run"]
        assert run["command"].startswith(("python benchmarks/", "mpirun -n ")), path
        assert {"cpu", "cores", "memory_gib", "load_average"} <= set(run["machine"]), path
        assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", run["date"]), path
        assert {"dolfinx_universal", "dolfinx", "numpy"} <= set(run["versions"]), path


def test_readme_numbers_are_on_the_page():
    """Each number of the README's comparison with gmsh appears on the measurements page."""
    readme = (ROOT / "README.md").read_text()
    page = (ROOT / "docs" / "measurements.md").read_text()
    section = readme.split("## Compared with gmsh and CutFEMx", 1)[1].split("**CutFEMx**", 1)[0]
    numbers = re.findall(r"\d+(?:\.\d+)?(?:e[+-]?\d+)?", section)
    assert numbers
    for number in numbers:
        assert number in page, number
