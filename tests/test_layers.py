"""Layering: the estimation core knows nothing of files, the CLI or the viewer, and only the
viz layer touches rerun. Checked statically (every import statement, including those inside
functions, and ``importlib.import_module``/``__import__`` calls with literal names) and
dynamically (a fresh interpreter importing every core module)."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

import mocap_calib

PACKAGE_DIR = Path(mocap_calib.__file__).resolve().parent
CORE_DIR = PACKAGE_DIR / "core"
VIZ_DIR = PACKAGE_DIR / "viz"

FORBIDDEN_IN_CORE = ("mocap_calib.io", "mocap_calib.cli", "mocap_calib.viz",
                     "mocap_calib.workflows", "rerun", "rerun_sdk", "typer", "click", "yaml",
                     "pandas")


def module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE_DIR.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_in_source(src: str, this: str, is_package: bool) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in ``src``, wherever it is (functions,
    classes, conditionals), relative imports resolved against module ``this``."""
    tree = ast.parse(src)
    package = this if is_package else this.rpartition(".")[0]
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            found.append((node.lineno, mod))
            # ``from mocap_calib import io`` imports the submodule too.
            found.extend((node.lineno, f"{mod}.{alias.name}") for alias in node.names)
        elif isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if name in ("import_module", "__import__") and node.args \
                    and isinstance(node.args[0], ast.Constant) \
                    and isinstance(node.args[0].value, str):
                found.append((node.lineno, node.args[0].value))
    return found


def imported_modules(path: Path) -> list[tuple[int, str]]:
    return imports_in_source(path.read_text(), module_name(path), path.name == "__init__.py")


def matches(mod: str, prefix: str) -> bool:
    return mod == prefix or mod.startswith(prefix + ".")


def test_scanner_sees_nested_relative_and_dynamic_imports() -> None:
    """The scanner itself must be able to fail."""
    src = ("import numpy\n"
           "def f():\n"
           "    import yaml\n"
           "    from ..io import euroc\n"
           "    from .. import viz\n"
           "    from .so3 import exp\n"
           "    import importlib\n"
           "    importlib.import_module('rerun')\n"
           "class A:\n"
           "    def g(self):\n"
           "        import pandas as pd\n")
    mods = [m for _, m in imports_in_source(src, "mocap_calib.core.probe", False)]
    for expected in ("numpy", "yaml", "mocap_calib.io", "mocap_calib.io.euroc",
                     "mocap_calib.viz", "mocap_calib.core.so3", "rerun", "pandas"):
        assert expected in mods, expected
    assert not any(matches(m, "mocap_calib.io") for m in ("mocap_calib.iox", "numpy"))


CORE_FILES = sorted(CORE_DIR.rglob("*.py"))


def test_core_files_found() -> None:
    names = {p.name for p in CORE_FILES}
    assert {"calibrate.py", "so3.py", "imu_model.py", "effects.py", "types.py"} <= names


@pytest.mark.parametrize("path", CORE_FILES, ids=lambda p: str(p.relative_to(PACKAGE_DIR)))
def test_core_imports_no_outer_layer(path: Path) -> None:
    bad = [(line, mod) for line, mod in imported_modules(path)
           for prefix in FORBIDDEN_IN_CORE if matches(mod, prefix)]
    assert not bad, f"{path.relative_to(PACKAGE_DIR)} imports {bad}"


def test_only_viz_imports_rerun() -> None:
    offenders = []
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        if VIZ_DIR in path.parents:
            continue
        for line, mod in imported_modules(path):
            if matches(mod, "rerun") or matches(mod, "rerun_sdk"):
                offenders.append(f"{path.relative_to(PACKAGE_DIR)}:{line} {mod}")
    assert not offenders, offenders


def test_importing_the_core_loads_no_outer_layer() -> None:
    modules = sorted(module_name(p) for p in CORE_FILES)
    code = (
        "import importlib, json, sys\n"
        f"for m in {modules!r}:\n"
        "    importlib.import_module(m)\n"
        "watch = ['rerun', 'typer', 'mocap_calib.io', 'mocap_calib.viz', 'mocap_calib.cli',\n"
        "         'mocap_calib.workflows']\n"
        "print(json.dumps(sorted(m for m in sys.modules\n"
        "                        if any(m == w or m.startswith(w + '.') for w in watch))))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=PACKAGE_DIR.parent)
    assert proc.returncode == 0, proc.stderr
    loaded = json.loads(proc.stdout.strip().splitlines()[-1])
    assert "mocap_calib.core.calibrate" in modules
    assert loaded == [], f"importing the core loaded {loaded}"


FORBIDDEN_IN_VIZ = ("mocap_calib.io", "mocap_calib.cli", "mocap_calib.workflows",
                    "mocap_calib.workflows_imu", "typer")


@pytest.mark.parametrize("path", sorted(VIZ_DIR.rglob("*.py")), ids=lambda p: p.name)
def test_viz_imports_only_the_core(path: Path) -> None:
    bad = [(line, mod) for line, mod in imported_modules(path)
           if any(matches(mod, f) for f in FORBIDDEN_IN_VIZ)]
    assert not bad, f"{path.name} imports outer layers: {bad}"
