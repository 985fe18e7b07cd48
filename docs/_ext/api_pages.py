"""Generate the API reference pages of dolfinx_universal at build time.

At ``builder-inited``, one page ``<api_output_dir>/<name>.md`` is written for every public
top-level entry of the package (those of ``api_modules`` first, in that order, then any
other one, so that a module or subpackage added later appears once it is there): for a
subpackage, its docstring and a section with ``automodule`` for each of its public modules,
found by ``pkgutil.walk_packages`` (so that modules split or renamed later are followed);
for a top-level module, its ``automodule``. Next to that folder go ``api_modules.inc`` (the
toctree of those pages, in that order) and ``api_toplevel.inc`` (not pages: ``api.md``
includes them): the table of the names exported by ``dolfinx_universal``, each linked to
the module that defines it (so that nothing is documented twice).

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
    # reST in a Markdown table: a role becomes its target as code, ``x`` becomes `x`.
    first = re.sub(r":(?:\w+:)?\w+:`~?([^`<]*?)\s*(?:<[^`>]*>)?`", r"`\1`", first)
    first = re.sub(r"``([^`]+)``", r"`\1`", first)
    return strip_internal_references(first).replace("|", "\\|")


def _public(name: str) -> bool:
    return not any(part.startswith("_") for part in name.split("."))


def present_modules(names: list[str]) -> list[str]:
    """The top-level modules and subpackages of ``names`` that exist, in that order, then
    every other public one."""
    pkg = importlib.import_module(PACKAGE)
    found = {m.name for m in pkgutil.iter_modules(pkg.__path__) if _public(m.name)}
    first = [n for n in names if n in found]
    return first + sorted(found - set(first))


def submodules(name: str) -> list[str]:
    """The public modules of the top-level entry ``name`` (dotted, without the package
    prefix): the entry itself, then, for a subpackage, every public module below it."""
    mod = importlib.import_module(f"{PACKAGE}.{name}")
    if not hasattr(mod, "__path__"):
        return [name]
    below = pkgutil.walk_packages(mod.__path__, prefix=f"{name}.")
    return [name, *sorted(m.name for m in below if _public(m.name))]


def _reexports(full: str) -> list[str]:
    """Names of ``__all__`` of module ``full`` defined in another module of the package:
    documented where they are defined, not again here."""
    mod = importlib.import_module(full)
    names = []
    for name in getattr(mod, "__all__", ()):
        home = getattr(getattr(mod, name, None), "__module__", None)
        if (
            isinstance(home, str)
            and home.startswith(f"{PACKAGE}.")
            and home != full
            and _public(home)
        ):
            names.append(name)
    return names


def _automodule(full: str, members: bool = True) -> str:
    options = "   :members:\n   :show-inheritance:\n" if members else ""
    skip = _reexports(full) if members else []
    if skip:
        options += f"   :exclude-members: {', '.join(skip)}\n"
    return f"```{{eval-rst}}\n.. automodule:: {full}\n{options}```\n"


def _page(name: str, modules: list[str]) -> str:
    full = f"{PACKAGE}.{name}"
    if modules == [name]:
        return f"# `{full}`\n\n" + _automodule(full)
    parts = [f"# `{full}`\n", _automodule(full, members=bool(_exports(full)))]
    listing = "".join(f"* {{py:mod}}`{PACKAGE}.{m}`\n" for m in modules[1:])
    parts.append(f"Modules:\n\n{listing}")
    parts.extend(f"## `{PACKAGE}.{m}`\n\n" + _automodule(f"{PACKAGE}.{m}") for m in modules[1:])
    return "\n".join(parts)


def _exports(full: str) -> list[str]:
    """The ``__all__`` of a module (empty when it has none: a subpackage's docstring)."""
    return list(getattr(importlib.import_module(full), "__all__", ()))


def _home(export: str, obj: object, loaded: dict[str, object]) -> str | None:
    """The documented module that defines ``export``: the one named by ``obj.__module__``
    when it lists it, else the first that lists it."""
    listing = [
        n for n, mod in loaded.items()
        if export in getattr(mod, "__all__", ()) and getattr(mod, export, None) is obj
    ]  # fmt: skip
    defined = getattr(obj, "__module__", None)
    for n in listing:
        if f"{PACKAGE}.{n}" == defined:
            return n
    return listing[0] if listing else None


def generate(app: Sphinx) -> None:
    out = Path(app.srcdir) / app.config.api_output_dir
    entries = present_modules(list(app.config.api_modules))
    documented: list[str] = []
    for name in entries:
        modules = submodules(name)
        documented.extend(modules)
        _write(out / f"{name}.md", _page(name, modules))
    for stale in out.glob("*.md"):
        if stale.stem not in entries:
            stale.unlink()
    rel = Path(app.config.api_output_dir).as_posix()
    _write(
        out.parent / "api_modules.inc",
        "```{toctree}\n:maxdepth: 1\n\n" + "".join(f"{rel}/{n}\n" for n in entries) + "```\n",
    )

    pkg = importlib.import_module(PACKAGE)
    loaded = {n: importlib.import_module(f"{PACKAGE}.{n}") for n in documented}
    rows = []
    for export in pkg.__all__:
        obj = getattr(pkg, export)
        home = _home(export, obj, loaded)
        if home is None:
            if isinstance(obj, type(pkg)) and obj.__name__.removeprefix(f"{PACKAGE}.") in loaded:
                mod = obj.__name__
                rows.append(f"| {{py:mod}}`{export} <{mod}>` | (module) | {_summary(obj)} |")
            else:
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
    "dolfinx_universal.curved.maps_tri.transfinite_map": _fix_transfinite_map,
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
