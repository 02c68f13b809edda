"""Issue 15's smaller items, each held by a test: no private typer API, every command module
registered (none swallowed), a licence metadata setuptools does not warn about."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

import mocap_calib
from mocap_calib.cli.commands import COMMANDS, register
from mocap_calib.cli.main import app

PACKAGE = Path(mocap_calib.__file__).parent
ROOT = PACKAGE.parent


def test_no_private_typer_module_is_imported() -> None:
    """typer's private modules change between the versions pyproject allows."""
    for path in PACKAGE.rglob("*.py"):
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
                names = [f"{node.value.id}.{node.attr}"]
            bad = [n for n in names if n.startswith("typer._")]
            assert not bad, f"{path.relative_to(ROOT)}:{node.lineno} uses {bad}"


def test_every_command_module_is_registered() -> None:
    """A command module that fails to import must fail loudly, not vanish from the CLI."""
    modules = {p.stem for p in (PACKAGE / "cli" / "commands").glob("*.py")} - {"__init__"}
    assert modules == set(COMMANDS)
    register()  # a run registers its own command only; all of them here
    registered = {c.name or c.callback.__name__ for c in app.registered_commands}
    assert registered == set(COMMANDS)
    init = (PACKAGE / "cli" / "commands" / "__init__.py").read_text()
    assert "except" not in init


def test_licence_is_an_spdx_expression() -> None:
    """A licence table or a licence classifier makes setuptools >= 77 warn on every install."""
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    project = meta["project"]
    assert isinstance(project["license"], str)
    assert not any(c.startswith("License ::") for c in project.get("classifiers", []))
