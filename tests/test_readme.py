"""The README's code runs, and its commands and figure are there."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def test_readme_python_blocks():
    blocks = re.findall(r"```python\n(.*?)```", README, flags=re.S)
    assert len(blocks) >= 3  # 2D, 3D, moving
    namespace: dict = {}  # the blocks build on each other, like a notebook's cells
    for code in blocks:
        exec(compile(code, "README.md", "exec"), namespace)  # each block asserts its results
    assert {"md", "md3", "moving"} <= set(namespace)


def test_readme_commands_and_figure():
    assert "bash .ci/venv python demos/quality.py --out out/quality" in README
    assert "bash .ci/test" in README
    assert "docs/figures/overview.png" in README
    assert len(README.splitlines()) <= 320
