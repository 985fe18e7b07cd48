"""Render the demos (plain Python, jupytext light or percent style) as MyST pages.

Nothing is executed. At ``builder-inited`` every ``*.py`` of ``demo_source_dir`` becomes
``<demo_output_dir>/<name>.md`` (rewritten only when its text changes; pages of removed
demos are deleted), which ``demos.md`` lists with a glob, so that the demos page follows
whatever is in ``demos/``:

* a comment block at the top level (lines starting with ``#``) that is followed by a blank
  line, a cell marker or the end of the file is Markdown (the leading ``# `` removed);
* a comment block attached to code (no blank line after it) stays in the code;
* ``# +`` / ``# -`` (light) and ``# %%`` / ``# %% [markdown]`` (percent) cells are honoured;
* a jupytext YAML header (``# ---`` ... ``# ---``) and a shebang or coding line are dropped;
* a leading module docstring is shown as Markdown, after the demo's title (the first
  Markdown cell when it starts with a level-1 heading; else the file name);
* references to internal design notes are dropped (``sanitize.py``);
* links to local files (``[text](path)``) become ``text (`path`)`` since they point
  into the repository, not into the documentation;
* the PNG figures committed under ``<demo_figures_dir>/<name>/`` (written by the demo's
  quick run, copied there by ``docs/make_figures.py``) are shown in a last section,
  "Figures".
"""

from __future__ import annotations

import ast
import os
import re
from pathlib import Path

from sanitize import strip_internal_references
from sphinx.application import Sphinx
from sphinx.util import logging

logger = logging.getLogger(__name__)

_MARKER = re.compile(r"^# ?(\+|-|%%.*)\s*$")
_LINK = re.compile(r"(?<!!)\[([^\]]+)\]\((?!https?://|mailto:|#)([^)\s]+)\)")


def _clean_markdown(text: str) -> str:
    text = _LINK.sub(lambda m: f"{m.group(1)} (`{m.group(2)}`)", text)
    return strip_internal_references(text)


def _uncomment(lines: list[str]) -> list[str]:
    out = []
    for line in lines:
        if line.startswith("# "):
            out.append(line[2:])
        elif line.startswith("#"):
            out.append(line[1:])
        else:
            out.append(line)
    return out


def _strip_header(lines: list[str]) -> tuple[list[str], str | None]:
    """Drop shebang, coding line and jupytext header; return the module docstring."""
    i = 0
    while i < len(lines) and (lines[i].startswith("#!") or re.match(r"^# .*coding[:=]", lines[i])):
        i += 1
    if i < len(lines) and lines[i].strip() == "# ---":
        j = i + 1
        while j < len(lines) and lines[j].strip() != "# ---":
            j += 1
        if j < len(lines):
            i = j + 1
    lines = lines[i:]
    docstring = None
    text = "\n".join(lines)
    try:
        tree = ast.parse(text)
    except SyntaxError:
        return lines, None
    if (
        tree.body
        and isinstance(tree.body[0], ast.Expr)
        and isinstance(tree.body[0].value, ast.Constant)
        and isinstance(tree.body[0].value.value, str)
    ):
        node = tree.body[0]
        docstring = ast.get_docstring(tree)
        lines = lines[: node.lineno - 1] + lines[node.end_lineno :]
    return lines, docstring


def _cells(lines: list[str]) -> list[tuple[str, list[str]]]:
    """Split a demo into ``("md" | "code", lines)`` cells."""
    cells: list[tuple[str, list[str]]] = []

    def add(kind: str, block: list[str]) -> None:
        while block and not block[0].strip():
            block = block[1:]
        while block and not block[-1].strip():
            block = block[:-1]
        if not block:
            return
        if cells and cells[-1][0] == kind:
            cells[-1][1].extend([""] + block)
        else:
            cells.append((kind, list(block)))

    n = len(lines)
    i = 0
    code: list[str] = []
    while i < n:
        line = lines[i]
        m = _MARKER.match(line)
        if m:
            add("code", code)
            code = []
            tag = m.group(1)
            i += 1
            if tag.startswith("%%") and "markdown" in tag:
                # A Markdown cell: its comment lines (up to the next marker or code line).
                block = []
                while i < n and not _MARKER.match(lines[i]):
                    if lines[i].strip() and not lines[i].startswith("#"):
                        break
                    block.append(lines[i])
                    i += 1
                add("md", _uncomment(block))
            elif tag == "+" or tag.startswith("%%"):
                block = []
                while i < n and not _MARKER.match(lines[i]):
                    block.append(lines[i])
                    i += 1
                if i < n and _MARKER.match(lines[i]).group(1) == "-":
                    i += 1
                add("code", block)
            continue
        if line.startswith("#") and (i == 0 or not lines[i - 1].strip() or not code):
            j = i
            while j < n and lines[j].startswith("#") and not _MARKER.match(lines[j]):
                j += 1
            ends = j == n or not lines[j].strip() or bool(_MARKER.match(lines[j]))
            if ends:
                add("code", code)
                code = []
                add("md", _uncomment(lines[i:j]))
                i = j
                continue
            code.extend(lines[i:j])
            i = j
            continue
        code.append(line)
        i += 1
    add("code", code)
    return cells


def figures_section(name: str, figures: list[str]) -> str:
    """The "Figures" section of demo ``name``: ``figures`` are paths from the source
    directory (``figures/demos/<name>/<file>.png``)."""
    if not figures:
        return ""
    parts = [
        "## Figures of the quick run\n",
        f"The figures of the quick run, `python demos/{name}.py --quick --out DIR` (coarser "
        "meshes and fewer steps than the full run, which writes the same files); "
        "`docs/make_figures.py` copies them here.\n",
    ]
    for fig in figures:
        file = Path(fig).name
        parts.append(
            f"```{{figure}} /{fig}\n:alt: {file} of demos/{name}.py (quick run)\n"
            f":width: 100%\n\n`{file}`\n```\n"
        )
    return "\n".join(parts)


def demo_to_myst(path: Path, download: str, figures: list[str] | None = None) -> str:
    """The MyST text of one demo (``figures``: see :func:`figures_section`)."""
    lines, docstring = _strip_header(path.read_text(encoding="utf-8").splitlines())
    cells = _cells(lines)
    parts: list[str] = []
    titled = bool(cells) and cells[0][0] == "md" and re.match(r"^#\s", cells[0][1][0])
    if docstring:  # after the demo's own title, or under one made from the file name
        if titled:
            cells[0] = ("md", [*cells[0][1][:1], "", *docstring.splitlines(), "", *cells[0][1][1:]])
        else:
            cells.insert(0, ("md", docstring.splitlines()))
    if not titled:
        parts.append(f"# `demos/{path.name}`\n")
    for kind, block in cells:
        if kind == "md":
            parts.append(_clean_markdown("\n".join(block)) + "\n")
        else:
            fence = "```"
            while any(line.startswith(fence) for line in block):
                fence += "`"
            parts.append(f"{fence}python\n" + "\n".join(block) + f"\n{fence}\n")
    parts.append(
        f"Source: {{download}}`demos/{path.name} <{download}>`; run it with "
        f"`python demos/{path.name}` (add `--quick` for a short run), also under "
        f"`mpirun -n 2`.\n"
    )
    section = figures_section(path.stem, figures or [])
    if section:
        parts.append(section)
    return "\n".join(parts)


def _write(path: Path, text: str) -> None:
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def generate(app: Sphinx) -> None:
    src = Path(app.config.demo_source_dir)
    out = Path(app.srcdir) / app.config.demo_output_dir
    out.mkdir(parents=True, exist_ok=True)
    demos = sorted(p for p in src.glob("*.py") if not p.name.startswith("_"))
    names = set()
    srcdir = Path(app.srcdir)
    for demo in demos:
        download = os.path.relpath(demo, out)
        pngs = sorted((srcdir / app.config.demo_figures_dir / demo.stem).glob("*.png"))
        figures = [png.relative_to(srcdir).as_posix() for png in pngs]
        _write(out / f"{demo.stem}.md", demo_to_myst(demo, download, figures))
        names.add(demo.stem)
    for stale in out.glob("*.md"):
        if stale.stem not in names:
            stale.unlink()
    if not demos:
        logger.warning("no demos found in %s", src)


def setup(app: Sphinx) -> dict:
    app.add_config_value("demo_source_dir", "../demos", "env")
    app.add_config_value("demo_output_dir", "_autogen/demos", "env")
    app.add_config_value("demo_figures_dir", "figures/demos", "env")
    app.connect("builder-inited", generate)
    return {"version": "0.1", "parallel_read_safe": True, "parallel_write_safe": True}
