"""Layering: which layer may import which, checked for every module of the package.

Checked statically (every import statement, including those inside functions, and
``importlib.import_module``/``__import__`` calls with literal names) and dynamically (a fresh
interpreter importing every core module loads no outer layer). The table below is the one in
DEVELOPERS.md.
"""

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

#: layer -> (package layers it may import, third-party top-level modules it may import).
#: Every layer may import the standard library, ``mocap_calib.errors`` and itself.
LAYERS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "core": ((), ("numpy", "scipy", "gtsam", "allantools", "numba")),
    "io": (("core",), ("numpy", "yaml", "rosbags", "pyulog", "pyarrow")),
    "sim": (("core",), ("numpy", "scipy")),
    "report": (("core",), ("numpy", "matplotlib")),
    "export": (("core", "io"), ("numpy", "yaml")),
    "viz": (("core", "report"), ("numpy", "rerun")),
    "workflows": (("core", "io", "sim", "report", "export", "viz"),
                  ("numpy", "scipy", "yaml", "gtsam")),
    "batch": (("core", "io", "report", "workflows"), ("numpy", "yaml", "dask",
                                                       "distributed")),
    "cli": (("workflows", "batch"), ("typer", "click")),
}
#: Modules at the package root: ``errors`` (imported by all), ``__init__``, ``__main__``.
ROOT_MODULES = {"mocap_calib", "mocap_calib.errors", "mocap_calib.__main__"}

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



def layer_of(path: Path) -> str | None:
    rel = path.relative_to(PACKAGE_DIR)
    return rel.parts[0] if len(rel.parts) > 1 else None


ALL_FILES = sorted(PACKAGE_DIR.rglob("*.py"))
STDLIB = set(sys.stdlib_module_names)


def test_every_package_has_a_layer() -> None:
    packages = {p.name for p in PACKAGE_DIR.iterdir() if (p / "__init__.py").is_file()}
    assert packages <= set(LAYERS), f"packages without a row in LAYERS: {packages - set(LAYERS)}"
    top = {p.stem for p in PACKAGE_DIR.glob("*.py")}
    assert top <= {"__init__", "__main__", "errors"}, f"modules outside any layer: {top}"


def violations(path: Path) -> list[str]:
    layer = layer_of(path)
    if layer is None:  # errors.py, __init__.py: standard library only; __main__.py: the CLI
        allowed_pkg: tuple[str, ...] = ("cli",) if path.name == "__main__.py" else ()
        allowed_ext: tuple[str, ...] = ()
        own = "mocap_calib.errors"
    else:
        allowed_pkg, allowed_ext = LAYERS[layer]
        own = f"mocap_calib.{layer}"
    bad = []
    for line, mod in imported_modules(path):
        top = mod.split(".")[0]
        if top == "mocap_calib":
            root = any(matches(mod, r) for r in ROOT_MODULES - {"mocap_calib"})
            root = root or mod == "mocap_calib"
            if root or matches(mod, own):
                continue
            if not any(matches(mod, f"mocap_calib.{a}") for a in allowed_pkg):
                bad.append(f"{line}: {mod}")
        elif top not in STDLIB and top not in allowed_ext and top != "__future__":
            bad.append(f"{line}: {mod}")
    return bad


@pytest.mark.parametrize("path", ALL_FILES, ids=lambda p: str(p.relative_to(PACKAGE_DIR)))
def test_layer_imports(path: Path) -> None:
    bad = violations(path)
    assert not bad, f"{path.relative_to(PACKAGE_DIR)} (layer {layer_of(path)}) imports {bad}"


def test_layer_rule_can_fail(tmp_path: Path) -> None:
    """A core module importing io or pandas, a cli module importing the core: all caught."""
    for layer, src in (("core", "import pandas\n"), ("core", "from mocap_calib.io import tum\n"),
                       ("io", "from mocap_calib.viz import recording\n"),
                       ("sim", "import rerun\n")):
        fake = PACKAGE_DIR / layer / "_probe_layers.py"
        try:
            fake.write_text(src)
            assert violations(fake), (layer, src)
        finally:
            fake.unlink()


CORE_FILES = sorted(CORE_DIR.rglob("*.py"))


def test_core_files_found() -> None:
    names = {p.name for p in CORE_FILES}
    assert {"calibrate.py", "so3.py", "imu_model.py", "effects.py", "types.py"} <= names


def test_importing_the_core_loads_no_outer_layer() -> None:
    modules = sorted(module_name(p) for p in CORE_FILES)
    # The core's own third-party libraries may load what they need (numba reads its config
    # with yaml when yaml is installed): only what the core's modules add on top counts (their
    # own imports are checked statically above).
    code = (
        "import importlib, json, sys\n"
        f"for m in {sorted(LAYERS['core'][1])!r}:\n"
        "    importlib.import_module(m)\n"
        "before = set(sys.modules)\n"
        f"for m in {modules!r}:\n"
        "    importlib.import_module(m)\n"
        "watch = ['rerun', 'typer', 'pandas', 'yaml', 'matplotlib', 'dask', 'rosbags',\n"
        "         'mocap_calib.io', 'mocap_calib.viz', 'mocap_calib.cli', 'mocap_calib.sim',\n"
        "         'mocap_calib.report', 'mocap_calib.workflows', 'mocap_calib.export',\n"
        "         'mocap_calib.batch']\n"
        "print(json.dumps(sorted(m for m in set(sys.modules) - before\n"
        "                        if any(m == w or m.startswith(w + '.') for w in watch))))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=PACKAGE_DIR.parent)
    assert proc.returncode == 0, proc.stderr
    loaded = json.loads(proc.stdout.strip().splitlines()[-1])
    assert "mocap_calib.core.pipeline.calibrate" in modules
    assert loaded == [], f"importing the core loaded {loaded}"


# --------------------------------------------------------------------------------------------
# Writers draw, they do not compute
# --------------------------------------------------------------------------------------------
#: The writers: the rerun recordings and the reports (text and HTML).
WRITERS = ("viz", "report")
#: What the writers may import of the core: the result and model types (the series they draw
#: are in ``core/result/series.py``, computed with the result), the policy's constants, and the
#: intrinsics commands' result records (``attitude_drift`` keeps its record beside its check).
#: No estimator module: the writers never call back into the solver.
WRITER_CORE = ("mocap_calib.core.model", "mocap_calib.core.result", "mocap_calib.core.policy",
               "mocap_calib.core.intrinsics.noise_result",
               "mocap_calib.core.intrinsics.multipos.result",
               "mocap_calib.core.intrinsics.attitude_drift")
WRITER_FILES = [p for p in ALL_FILES if layer_of(p) in WRITERS]


def writer_violations(path: Path) -> list[str]:
    """Imports of core modules outside :data:`WRITER_CORE`, and reads of a result's solver
    diagnostics (``.diagnostics``, ``.trace``): a writer gets its series handed over."""
    bad = [f"{line}: {mod}" for line, mod in imported_modules(path)
           if matches(mod, "mocap_calib.core")
           and not any(matches(mod, ok) for ok in WRITER_CORE)]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Attribute) and node.attr in ("diagnostics", "trace"):
            bad.append(f"{node.lineno}: .{node.attr}")
    return bad


def test_writer_files_found() -> None:
    names = {p.name for p in WRITER_FILES}
    assert {"recording.py", "residuals.py", "calibration.py", "text.py"} <= names


@pytest.mark.parametrize("path", WRITER_FILES, ids=lambda p: str(p.relative_to(PACKAGE_DIR)))
def test_writers_import_no_estimator(path: Path) -> None:
    bad = writer_violations(path)
    assert not bad, f"{path.relative_to(PACKAGE_DIR)} (a writer) uses {bad}"


def test_writer_rule_can_fail() -> None:
    """A writer importing the prediction, the session's preparation or the position stage
    (also lazily, or for type hints), or reading a result's diagnostics: all caught."""
    for layer, src in (("viz", "from mocap_calib.core.diagnosis.predict import predict_imu\n"),
                       ("report", "def f():\n    from mocap_calib.core.prepare import session\n"),
                       ("report", "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                  "    from mocap_calib.core.position.stage import X\n"),
                       ("viz", "def f(r):\n    return r.diagnostics.residuals\n")):
        fake = PACKAGE_DIR / layer / "_probe_writers.py"
        try:
            fake.write_text(src)
            assert writer_violations(fake), (layer, src)
        finally:
            fake.unlink()


def test_importing_the_writers_loads_no_estimator() -> None:
    """Every writer module imported in a fresh interpreter loads none of the calibration's
    estimator packages."""
    modules = sorted(module_name(p) for p in WRITER_FILES)
    estimators = [f"mocap_calib.core.{p}" for p in ("prepare", "clock", "position",
                                                    "uncertainty", "checks", "pipeline",
                                                    "diagnosis", "groundtruth")]
    estimators += ["mocap_calib.core.gtsam_tools", "mocap_calib.core.stages.attitude",
                   "mocap_calib.core.stages.velocity"]
    code = ("import importlib, json, sys\n"
            f"for m in {modules!r}:\n"
            "    importlib.import_module(m)\n"
            f"print(json.dumps(sorted(m for m in sys.modules if any(m == e or m.startswith(e + '.')"
            f" for e in {estimators!r}))))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=PACKAGE_DIR.parent)
    assert proc.returncode == 0, proc.stderr
    assert "mocap_calib.viz.recording" in modules
    loaded = json.loads(proc.stdout.strip().splitlines()[-1])
    assert loaded == [], f"importing the writers loaded {loaded}"
