"""The README's code runs."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np


def test_readme_python_blocks():
    text = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks
    namespace: dict = {}  # the blocks build on each other, like a notebook's cells
    for code in blocks:
        exec(compile(code, "README.md", "exec"), namespace)
    if "area" in namespace:
        assert abs(namespace["area"] - np.pi) < 1e-6
