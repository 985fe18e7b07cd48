"""Generate the API reference pages of dolfinx_universal at build time.

At ``builder-inited``, for every public module of the package (those of ``api_modules``
first, in that order, then any other one, so that a module added later appears once it is
there), a page
``<api_output_dir>/<module>.md`` with ``automodule`` is written, plus
``api_modules.inc`` (the toctree of those pages, in that order) and ``api_toplevel.inc``
next to that folder (not pages: ``api.md`` includes them): the table of the names
exported by ``dolfinx_universal``, each linked to where it is documented (so that nothing
is documented twice).

Docstrings pass through ``autodoc-process-docstring``, which drops references to internal
design notes (``sanitize.py``) and works around the docstrings of the current tree that
Sphinx warns about (``_KNOWN_FIXES``, ``_split_ivars``; each is a no-op once the source
is fixed; ``DOCS_NO_WORKAROUNDS=1 bash .ci/docs`` builds without them).
"""

from __future__ import annotations

import importlib
import os
import pkgutil
import re
from pathlib import Path

from sanitize import strip_internal_references
from sphinx.application import Sphinx

PACKAGE = "dolfinx_universal"


def _write(path: Path, text: str) -> None:
    if not path.exists() or path.read_text(encoding="utf-8") != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def _summary(obj: object) -> str:
    if isinstance(obj, (int, float, str)):
        return f"constant `{obj!r}`"
    doc = (getattr(obj, "__doc__", None) or "").strip()
    if not doc:
        return ""
    first = doc.split("\n\n")[0].replace("\n", " ").strip()
    return strip_internal_references(first).replace("|", "\\|")


def present_modules(names: list[str]) -> list[str]:
    """The modules of ``names`` that exist, in that order, then every other public module."""
    pkg = importlib.import_module(PACKAGE)
    found = {m.name for m in pkgutil.iter_modules(pkg.__path__) if not m.name.startswith("_")}
    first = [n for n in names if n in found]
    return first + sorted(found - set(first))


def generate(app: Sphinx) -> None:
    out = Path(app.srcdir) / app.config.api_output_dir
    modules = present_modules(list(app.config.api_modules))
    for name in modules:
        full = f"{PACKAGE}.{name}"
        _write(
            out / f"{name}.md",
            f"# `{full}`\n\n```{{eval-rst}}\n.. automodule:: {full}\n"
            "   :members:\n   :show-inheritance:\n```\n",
        )
    for stale in out.glob("*.md"):
        if stale.stem not in modules:
            stale.unlink()
    rel = Path(app.config.api_output_dir).as_posix()
    _write(
        out.parent / "api_modules.inc",
        "```{toctree}\n:maxdepth: 1\n\n" + "".join(f"{rel}/{n}\n" for n in modules) + "```\n",
    )

    pkg = importlib.import_module(PACKAGE)
    loaded = {n: importlib.import_module(f"{PACKAGE}.{n}") for n in modules}
    rows = []
    for export in pkg.__all__:
        obj = getattr(pkg, export)
        home = None
        for name, mod in loaded.items():
            if export in getattr(mod, "__all__", ()) and getattr(mod, export) is obj:
                home = name
                break
        if home is None:
            rows.append(f"| `{export}` | (not in a documented module) | {_summary(obj)} |")
            continue
        target = f"{PACKAGE}.{home}.{export}"
        rows.append(f"| {{py:obj}}`~{target}` | `{home}` | {_summary(obj)} |")
    _write(
        out.parent / "api_toplevel.inc",
        "| name | module | summary |\n|---|---|---|\n" + "\n".join(rows) + "\n",
    )


def _fix_transfinite_map(lines: list[str]) -> None:
    """A formula written as an inline literal over two lines becomes a literal block."""
    for i in range(len(lines) - 1):
        first, second = lines[i], lines[i + 1]
        if first.startswith("``G(x) = [") and second.lstrip().startswith("+ [") and "``" in second:
            lines[i : i + 2] = [
                "The blend::",
                "",
                "    " + first[2:],
                "    " + second.replace("``", "", 1).rstrip(),
                "",
            ]
            return


def _fix_moving_domain(lines: list[str]) -> None:
    """A paragraph after the last parameter is read as one more parameter by napoleon."""
    for i, line in enumerate(lines):
        if line.startswith(":param See :meth:`from_motion`"):
            lines[i : i + 1] = ["", line[len(":param ") :].rstrip().removesuffix(":")]
            return


def _split_ivars(lines: list[str]) -> None:
    """``:ivar x, y: text`` (an Attributes entry naming several attributes, which napoleon
    passes on as is and Sphinx reads as type ``x,`` and name ``y``) becomes one field per
    name."""
    i = 0
    while i < len(lines):
        m = re.match(r"^:ivar ([\w, ]+?, [\w, ]+?):(.*)$", lines[i])
        if not m:
            i += 1
            continue
        j = i + 1
        while j < len(lines) and lines[j].startswith(" "):
            j += 1
        rest = [line.strip() for line in lines[i + 1 : j]]
        block = []
        for name in (n.strip() for n in m.group(1).split(",")):
            head = f":ivar {name}:"
            block.append(head + m.group(2))
            block.extend(" " * (len(head) + 1) + line for line in rest)
        lines[i:j] = block
        i += len(block)


# Docstrings of the current tree that Sphinx warns about, fixed while the documentation is
# built until the source is fixed (each fix is a no-op then).
_KNOWN_FIXES = {
    "dolfinx_universal.curved.maps.transfinite_map": _fix_transfinite_map,
    "dolfinx_universal.moving.domain.MovingDomain": _fix_moving_domain,
}


def process_docstring(app, what, name, obj, options, lines) -> None:  # noqa: ARG001
    text = "\n".join(lines)
    new = strip_internal_references(text)
    if new != text:
        lines[:] = new.split("\n")
    if os.environ.get("DOCS_NO_WORKAROUNDS"):  # to see whether they are still needed
        return
    _split_ivars(lines)
    fix = _KNOWN_FIXES.get(name)
    if fix is not None:
        fix(lines)


def setup(app: Sphinx) -> dict:
    app.add_config_value("api_output_dir", "_autogen/api", "env")
    app.add_config_value("api_modules", [], "env")
    app.connect("builder-inited", generate)
    app.connect("autodoc-process-docstring", process_docstring)
    return {"version": "0.1", "parallel_read_safe": True, "parallel_write_safe": True}
