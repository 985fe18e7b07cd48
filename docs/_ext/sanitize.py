"""Text fixes applied to demo and docstring text while the documentation is built.

``strip_internal_references`` drops the references to internal design notes (section
signs of a design document) that some demos and docstrings still carry: they point to
nothing a reader of the documentation has. Each rule is a no-op once the source no longer
has the pattern.
"""

from __future__ import annotations

import re

_RULES: list[tuple[re.Pattern[str], str]] = [
    (re.compile(r"\(SPEC\s*§[\d.\-–§, ]*?\d,\s*(?=[a-z])"), "("),  # "(SPEC §6, collective)"
    (re.compile(r"\s*\(SPEC[^)]*\)"), ""),  # "(SPEC §7.1)"
    (re.compile(r",\s*SPEC\s*§[^)]*(?=\))"), ""),  # "(a universal mesh, SPEC §5)"
    (re.compile(r"the source\s+of SPEC\s*§\s*[\d.]*\d"), "the problem statement"),
    (re.compile(r"\bof SPEC\s*§\s*[\d.]*\d"), "of the method"),  # "conditions of SPEC §6"
    (re.compile(r"\bSPEC's\s+"), "the "),
    (re.compile(r"\s*\bSPEC\s*§\s*[\d.\-–, §]*\d"), ""),  # anything left
]


def strip_internal_references(text: str) -> str:
    for pattern, repl in _RULES:
        text = pattern.sub(repl, text)
    return text
