"""The layout of rig/ (DESIGN.md, "Layout of rig/"): the rooms of the table, no import circle between files
(lazy imports count), no private name imported across modules."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
RIG = REPO / "rig"
DESIGN = REPO.parent / "shared" / "DESIGN.md"


def _modules() -> dict[str, Path]:
    out = {}
    for p in RIG.rglob("*.py"):
        parts = p.relative_to(REPO).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = p
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> list[tuple[str, list[str], int]]:
    """(module imported, names taken from it, line) for every import of ``path``, lazy ones included."""
    out = []
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, [], node.lineno) for a in node.names if a.name.split(".")[0] == "rig"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                mod = ".".join([*base, node.module] if node.module else base)
            else:
                mod = node.module or ""
            if mod.split(".")[0] != "rig":
                continue
            names = [a.name for a in node.names]
            submodules = [f"{mod}.{n}" for n in names if f"{mod}.{n}" in modules]
            out += [(s, [], node.lineno) for s in submodules]
            out.append((mod, [n for n in names if f"{mod}.{n}" not in modules], node.lineno))
    return out


def test_rooms_are_the_design_table() -> None:
    rooms = {p.name for p in RIG.iterdir() if (p / "__init__.py").exists()}
    assert rooms == {"core", "analysis", "store", "data", "record", "live", "replay", "sim", "evaluate", "export",
                     "ppk", "workflows", "cli"}
    assert sorted(p.name for p in RIG.glob("*.py")) == ["__init__.py", "__main__.py"]
    if not DESIGN.exists():
        pytest.skip(f"{DESIGN} is not beside the checkout")
    table = re.findall(r"^\| `(\w+)/` \|", DESIGN.read_text(), flags=re.M)
    assert set(table) == rooms


def test_no_private_name_is_imported_across_modules() -> None:
    modules = _modules()
    bad = []
    for name, path in modules.items():
        for mod, names, line in _imports(name, path, modules):
            leaf = mod.rsplit(".", 1)[-1]
            private = [n for n in names if n.startswith("_")] + ([leaf] if leaf.startswith("_") and mod != name
                                                                  and not leaf.startswith("__") else [])
            if private and mod != name:
                bad.append(f"{path.relative_to(REPO)}:{line}: {mod} {private}")
    assert bad == [], "\n".join(bad)


def test_no_import_circle_between_files() -> None:
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        deps = set()
        for mod, _names, _line in _imports(name, path, modules):
            while mod not in modules and "." in mod:
                mod = mod.rpartition(".")[0]
            if mod in modules and mod != name:
                deps.add(mod)
        graph[name] = deps
    # Tarjan's strongly connected components: any with more than one module is a circle
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    circles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
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
                circles.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    assert circles == []
