"""Measures of the package's layout: import circles, imports hidden in functions, private
names imported across subpackages, branches on the dimension, long functions.

Run ``python tests/layout_metrics.py [package_dir]`` for a report; ``test_layout.py``
asserts the targets.
"""

from __future__ import annotations

import ast
import sys
from dataclasses import dataclass, field
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parents[1] / "dolfinx_universal"

DIMENSION_NAMES = {"tdim", "gdim", "dim", "dimension"}
"""Names and attributes that hold a dimension (``topology.dim``, ``boundary.gdim``, ...)."""
CELL_NAMES = {"triangle", "tetrahedron"}


def _is_dimension(node: ast.AST) -> bool:
    """Whether an expression asks for the dimension: a name or attribute of
    :data:`DIMENSION_NAMES`, the width ``a.shape[1]`` / ``a.shape[-1]`` of a point or cell
    array, ``getattr(x, "gdim", ...)``, or a cell type."""
    if isinstance(node, ast.Name):
        return node.id in DIMENSION_NAMES
    if isinstance(node, ast.Attribute):
        return node.attr in DIMENSION_NAMES or node.attr in ("cell_type", "cell_name")
    if isinstance(node, ast.Subscript):
        value, index = node.value, node.slice
        if isinstance(value, ast.Attribute) and value.attr == "shape":
            text = ast.unparse(index)
            return text in ("1", "-1")
    if isinstance(node, ast.Call):
        if isinstance(node.func, ast.Name) and node.func.id in ("int", "len"):
            return any(_is_dimension(a) for a in node.args)
        if isinstance(node.func, ast.Name) and node.func.id == "getattr" and len(node.args) > 1:
            arg = node.args[1]
            return isinstance(arg, ast.Constant) and arg.value in DIMENSION_NAMES
    return False


def _is_dimension_value(node: ast.AST) -> bool:
    """2, 3, a cell name or a cell type, or a tuple of them."""
    if isinstance(node, ast.Constant):
        return node.value in (2, 3) or node.value in CELL_NAMES
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return any(_is_dimension_value(e) for e in node.elts)
    if isinstance(node, ast.Attribute):
        return node.attr in CELL_NAMES
    return False


def tests_dimension(test: ast.AST) -> bool:
    """Whether a condition compares the dimension with a dimension (or cell name)."""
    for node in ast.walk(test):
        if isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            if any(_is_dimension(a) for a in sides) and any(_is_dimension_value(b) for b in sides):
                return True
    return False


def is_argument_check(node: ast.If | ast.IfExp | ast.While) -> bool:
    """A branch whose body only raises: an argument check, not a branch of the algorithm."""
    body = node.body if isinstance(node.body, list) else [node.body]
    return not getattr(node, "orelse", None) and all(isinstance(b, ast.Raise) for b in body)


@dataclass
class Module:
    name: str
    path: Path
    tree: ast.Module
    source: str
    imports: list[tuple[str, str | None, bool]] = field(default_factory=list)
    """(target module, imported name or None, inside a function)."""


def _module_name(path: Path, root: Path) -> str:
    rel = path.relative_to(root.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def load(root: Path = PACKAGE_DIR) -> dict[str, Module]:
    """Every module of the package under ``root`` with its imports of the package."""
    mods: dict[str, Module] = {}
    for path in sorted(root.rglob("*.py")):
        src = path.read_text(encoding="utf-8")
        mods[_module_name(path, root)] = Module(_module_name(path, root), path, ast.parse(src), src)
    pkg = root.name
    for mod in mods.values():
        is_pkg = mod.path.name == "__init__.py"
        parents: dict[ast.AST, ast.AST] = {}
        for node in ast.walk(mod.tree):
            for child in ast.iter_child_nodes(node):
                parents[child] = node
        for node in ast.walk(mod.tree):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                base = mod.name.split(".") if is_pkg else mod.name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if not (target == pkg or target.startswith(pkg + ".")):
                continue
            in_function, p = False, parents.get(node)
            type_only = False
            while p is not None:
                if isinstance(p, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    in_function = True
                if isinstance(p, ast.If) and "TYPE_CHECKING" in ast.unparse(p.test):
                    type_only = True
                p = parents.get(p)
            if type_only:
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in mods:
                    mod.imports.append((sub, None, in_function))
                else:
                    mod.imports.append((target, alias.name, in_function))
    return mods


def subpackage(name: str) -> str:
    """The subpackage of a module (``dolfinx_universal.conforming.relax`` ->
    ``conforming``; top-level modules are their own)."""
    parts = name.split(".")
    return parts[1] if len(parts) > 1 else ""


def import_cycles(mods: dict[str, Module]) -> list[list[str]]:
    """Strongly connected sets of more than one module (imports anywhere in a module)."""
    graph = {m: {t for t, _, _ in mod.imports if t in mods and t != m} for m, mod in mods.items()}
    # A package's __init__ importing its own modules is not a circle with them.
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(max(10000, sys.getrecursionlimit()))
    for v in graph:
        if v not in index:
            visit(v)
    return out


def function_imports(mods: dict[str, Module]) -> list[tuple[str, str]]:
    """Imports of the package made inside functions (module, target)."""
    return [(m, t) for m, mod in mods.items() for t, _, inside in mod.imports if inside]


def private_cross_imports(mods: dict[str, Module]) -> list[tuple[str, str, str]]:
    """Private names (``_x``, not dunder) imported from another subpackage or top-level
    module: (module, target, name)."""
    out = []
    for m, mod in mods.items():
        for target, name, _ in mod.imports:
            private_module = any(
                p.startswith("_") and not p.startswith("__") for p in target.split(".")
            )
            private_name = name is not None and name.startswith("_") and not name.startswith("__")
            if (private_name or private_module) and subpackage(target) != subpackage(m):
                out.append((m, target, name or ""))
            elif private_name and subpackage(m) == "" and target != m:
                out.append((m, target, name or ""))
    return out


def dimension_branches(mods: dict[str, Module], argument_checks: bool = False) -> dict[str, int]:
    """Branches (``if``/``elif``/conditional expressions, ``while``) that test the
    dimension, per module: those of the algorithm, or (``argument_checks``) those whose
    body only raises."""
    counts: dict[str, int] = {}
    for m, mod in mods.items():
        n = 0
        for node in ast.walk(mod.tree):
            if isinstance(node, (ast.If, ast.IfExp, ast.While)) and tests_dimension(node.test):
                n += is_argument_check(node) == argument_checks
        if n:
            counts[m] = n
    return counts


def long_functions(mods: dict[str, Module], limit: int = 100) -> list[tuple[str, str, int]]:
    """Functions longer than ``limit`` lines, docstring excluded: (module, name, lines)."""
    out = []
    for m, mod in mods.items():
        for node in ast.walk(mod.tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                body = node.body
                start = body[0].lineno
                if (
                    isinstance(body[0], ast.Expr)
                    and isinstance(body[0].value, ast.Constant)
                    and isinstance(body[0].value.value, str)
                    and len(body) > 1
                ):
                    start = body[1].lineno
                length = (node.end_lineno or start) - start + 1
                if length > limit:
                    out.append((m, node.name, length))
    return sorted(out, key=lambda r: -r[2])


def report(root: Path = PACKAGE_DIR) -> str:
    mods = load(root)
    lines = [f"modules: {len(mods)}, lines: {sum(m.source.count(chr(10)) for m in mods.values())}"]
    cycles = import_cycles(mods)
    lines.append(f"import circles: {len(cycles)} {cycles}")
    fi = function_imports(mods)
    lines.append(f"imports inside functions: {len(fi)}")
    pc = private_cross_imports(mods)
    lines.append(f"private names imported across subpackages: {len(pc)}")
    lines += [f"  {m} <- {t} {n}" for m, t, n in pc]
    db = dimension_branches(mods)
    lines.append(f"dimension branches: {sum(db.values())}")
    lines += [f"  {m}: {n}" for m, n in sorted(db.items(), key=lambda r: -r[1])]
    checks = dimension_branches(mods, argument_checks=True)
    lines.append(f"argument checks on the dimension (body only raises): {sum(checks.values())}")
    lf = long_functions(mods)
    lines.append(f"functions over 100 lines: {len(lf)}")
    lines += [f"  {m}.{n}: {k}" for m, n, k in lf]
    return "\n".join(lines)


if __name__ == "__main__":
    print(report(Path(sys.argv[1]).resolve() if len(sys.argv) > 1 else PACKAGE_DIR))
