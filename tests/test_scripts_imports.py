"""Every name the scripts import from the package exists: a study or benchmark runs for many
minutes before its table step, so a name moved inside the package would otherwise surface only
at the end of a long run. Function-level imports are checked too (parsed, not executed)."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

SCRIPTS = sorted((Path(__file__).resolve().parents[1] / "scripts").glob("*.py"))


def _package_imports(path: Path) -> list[tuple[str, str, int]]:
    """(module, name, line) of every ``from mocap_calib... import name`` in ``path``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    return [(node.module, alias.name, node.lineno)
            for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.module
            and node.module.split(".")[0] == "mocap_calib"
            for alias in node.names]


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: p.name)
def test_script_imports_exist(path: Path) -> None:
    missing = []
    for module, name, line in _package_imports(path):
        mod = importlib.import_module(module)
        if not hasattr(mod, name):
            try:  # a submodule imported by name
                importlib.import_module(f"{module}.{name}")
            except ModuleNotFoundError:
                missing.append(f"{path.name}:{line}: {module}.{name}")
    assert not missing, "names the package no longer has: " + "; ".join(missing)


def test_the_check_sees_a_moved_name(tmp_path: Path) -> None:
    """The parse finds function-level imports (where the moved name was)."""
    script = tmp_path / "s.py"
    script.write_text("def f():\n    from mocap_calib.sim.flight import NO_SUCH_NAME\n")
    assert _package_imports(script) == [("mocap_calib.sim.flight", "NO_SUCH_NAME", 2)]
    assert not hasattr(importlib.import_module("mocap_calib.sim.flight"), "NO_SUCH_NAME")
