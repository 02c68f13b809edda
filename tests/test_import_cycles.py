"""No import cycles: between modules (every import counts: top-level, inside functions, under
``TYPE_CHECKING``) and between the core's packages, which follow the data flow
(``docs/architecture.md``); no module imports another package's private name."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from test_layers import ALL_FILES, PACKAGE_DIR, imports_in_source, module_name

MODULES = {module_name(p): p for p in ALL_FILES}


def _target(mod: str) -> str | None:
    """The package module an import names (``a.b.c`` where ``c`` is a function: ``a.b``)."""
    while mod and mod not in MODULES:
        mod = mod.rpartition(".")[0]
    return mod or None


def module_graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for name, path in MODULES.items():
        deps = set()
        for _, mod in imports_in_source(path.read_text(), name, path.name == "__init__.py"):
            t = _target(mod) if mod.startswith("mocap_calib") else None
            # A package's __init__ is imported on the way to any of its modules: not an edge.
            if t and t != name and not (path.name != "__init__.py" and name.startswith(t + ".")):
                deps.add(t)
        graph[name] = deps
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
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

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_cycle_finder_can_fail() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_module_import_cycle() -> None:
    found = cycles(module_graph())
    assert not found, f"import cycles: {found}"


def core_package(mod: str) -> str | None:
    """``mocap_calib.core.position.engine`` -> ``position``; core root modules are their own
    node (``graph``, ``options``)."""
    parts = mod.split(".")
    if parts[:2] != ["mocap_calib", "core"] or len(parts) < 3:
        return None
    return parts[2]


def test_core_packages_follow_the_data_flow() -> None:
    graph: dict[str, set[str]] = {}
    for name, deps in module_graph().items():
        a = core_package(name)
        if a is None:
            continue
        graph.setdefault(a, set()).update(
            b for d in deps if (b := core_package(d)) is not None and b != a)
    found = cycles(graph)
    assert not found, f"core packages import each other in a circle: {found}"


def _private_imports(path: Path) -> list[str]:
    name = module_name(path)
    pkg = name.rsplit(".", 1)[0] if path.name != "__init__.py" else name
    top = ".".join(name.split(".")[:2])  # mocap_calib.<layer>
    bad = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and not node.level:
            src_top = ".".join(node.module.split(".")[:2])
            for alias in node.names:
                if alias.name.startswith("_") and src_top != top:
                    bad.append(f"{node.module}.{alias.name}")
    return bad if not pkg.startswith("mocap_calib.viz") else [
        b for b in bad if not b.startswith("mocap_calib.viz._rerun")]


@pytest.mark.parametrize("path", ALL_FILES, ids=lambda p: str(p.relative_to(PACKAGE_DIR)))
def test_no_private_name_from_another_package(path: Path) -> None:
    bad = _private_imports(path)
    assert not bad, f"{path.relative_to(PACKAGE_DIR)} imports private names {bad}"


def test_folders_stay_small() -> None:
    """A folder of more than 12 modules no longer reads at a glance: split it by capability."""
    big = {str(d.relative_to(PACKAGE_DIR)): n for d in PACKAGE_DIR.rglob("*")
           if d.is_dir() and d.name != "__pycache__"
           and (n := len([p for p in d.glob("*.py") if p.name != "__init__.py"])) > 12}
    assert not big, f"folders over 12 modules: {big}"
