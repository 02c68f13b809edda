"""The base parameters are asked for through their registry (``core/model/parameters.py``:
``PARAMETERS``, the constants ``ROTATION`` ..., ``Parameter.value_key`` / ``sigma_key`` /
``symbol`` at the file boundary), never by a string: no module outside the registry indexes,
looks up, compares or builds a mapping with a parameter's name, symbol or file key.

The check walks every module's syntax tree for such a string used as a subscript
(``cov["rotation"]``), the key argument of ``get``/``pop``/``setdefault``/``getattr``/
``setattr``/``hasattr``, an operand of ``==``, ``!=``, ``in``, ``not in`` (also inside a tuple,
list or set), or a key of a dict literal (``{"R_MI": "rotation"}``: a hand translation). A
comparison with an effect's ``acts_on`` is left alone: ``gravity`` is also the kind of the
``|g|`` effect.
"""

from __future__ import annotations

import ast
from pathlib import Path

from mocap_calib.core.model.parameters import PARAMETERS

PACKAGE = Path(__file__).resolve().parents[1] / "mocap_calib"

#: Modules allowed to use the strings, and why. Each entry is a place the strings mean
#: something else or a module outside this registry's reach; the list only shrinks.
ALLOWED = {
    # The registry itself: names are what it maps to records.
    "mocap_calib/core/model/parameters.py",
    # The effect registry: the clock offset's effect record carries the name it shares.
    "mocap_calib/core/model/effects.py",
    # Intrinsics files (multipos, the drift check) have keys of their own that share the words
    # (``gyro_bias`` of M_g w + b_g); ``--gravity`` of multipos is an option.
    "mocap_calib/core/intrinsics/multipos/params.py",
    "mocap_calib/core/intrinsics/multipos/quality.py",
    "mocap_calib/core/intrinsics/multipos/result.py",
    "mocap_calib/core/intrinsics/attitude_drift.py",
    "mocap_calib/workflows/imu/drift.py",
    "mocap_calib/workflows/imu/multipos.py",
    # The measurement model's Jacobian blocks (d/d bias), named as the graph's layout names
    # its columns, and the position stage (its blocks, priors and iteration records, which
    # the recording's solver panel draws).
    "mocap_calib/core/model/imu_model.py",
    "mocap_calib/core/position/engine.py",
    "mocap_calib/core/position/graph.py",
    "mocap_calib/core/position/settle.py",
    "mocap_calib/viz/recording.py",
    # The first stages' range priors (RANGE_SIGMA by block).
    "mocap_calib/core/stages/attitude.py",
    "mocap_calib/core/stages/velocity.py",
    # File boundary outside the core: recognising a result file by its keys; the readers'
    # options (``rotation``: the form of a Vicon export's rotations).
    "mocap_calib/io/result_files.py",
    "mocap_calib/io/reading.py",
    # The coarse clock search's own file form (its candidates' ``time_offset``).
    "mocap_calib/core/clock/search.py",
}

#: Folders allowed whole: the simulator writes its truth files from its own draws (and its
#: presets name effects), independently of the estimator's registries.
ALLOWED_FOLDERS = ("mocap_calib/sim/",)

_QUERY_CALLS = {"get", "pop", "setdefault", "has", "endswith", "startswith"}
_ATTR_CALLS = {"getattr", "setattr", "hasattr"}


def names() -> set[str]:
    """Every string a parameter goes by: name, symbol, file keys, result field names."""
    out = set()
    for p in PARAMETERS.values():
        out |= {p.name, p.symbol, p.sigma_key, *p.value_key, f"sigma_{p.name}"}
    return out


def _strings(node: ast.AST | None) -> list[ast.Constant]:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node]
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return [c for e in node.elts for c in _strings(e)]
    return []


def queries(tree: ast.AST, words: set[str]) -> list[tuple[int, str]]:
    """(line, string) of every parameter string used to ask for a parameter in ``tree``."""
    found: list[ast.Constant] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript):
            found += _strings(node.slice)
        elif isinstance(node, ast.Call):
            if isinstance(node.func, ast.Attribute) and node.func.attr in _QUERY_CALLS:
                found += _strings(node.args[0]) if node.args else []
            elif isinstance(node.func, ast.Name) and node.func.id in _ATTR_CALLS:
                found += _strings(node.args[1]) if len(node.args) > 1 else []
        elif isinstance(node, ast.Compare) and all(
                isinstance(op, (ast.Eq, ast.NotEq, ast.In, ast.NotIn)) for op in node.ops):
            sides = (node.left, *node.comparators)
            if any(isinstance(x, ast.Attribute) and x.attr == "acts_on" for x in sides):
                continue  # an effect's kind ("gravity": |g|), not a parameter
            for side in sides:
                found += _strings(side)
        elif isinstance(node, ast.Dict):
            found += [c for k in node.keys for c in _strings(k)]
    return sorted({(c.lineno, c.value) for c in found if c.value in words})


def test_no_module_asks_for_a_parameter_by_name() -> None:
    words = names()
    assert {"rotation", "R_MI", "T_marker_imu", "gravity_in_mocap", "t_d"} <= words
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = str(path.relative_to(PACKAGE.parent))
        if rel in ALLOWED or rel.startswith(ALLOWED_FOLDERS):
            continue
        for line, word in queries(ast.parse(path.read_text()), words):
            bad.append(f"{rel}:{line}: {word!r}")
    assert not bad, ("base parameters asked for by a string (use the registry: PARAMETERS, "
                     "ROTATION..., Parameter.value_key / sigma_key / symbol):\n"
                     + "\n".join(bad))


def test_every_allowed_module_exists() -> None:
    """An entry of a module that is gone or renamed would hide nothing and mislead."""
    root = PACKAGE.parent
    assert not [m for m in (*ALLOWED, *ALLOWED_FOLDERS) if not (root / m).exists()]


def test_the_check_catches_each_form() -> None:
    """The walker sees every form (so a pass above is not a blind spot)."""
    src = ("cov['rotation']\nd.get('R_MI')\ngetattr(r, 'sigma_rotation')\nx == 't_d'\n"
           "'translation' in cov\nk in ('p_MI', 'other')\nm = {'gravity_in_mocap': 1}\n"
           "f('rotation')\ns = 'T_marker_imu'\ne.acts_on == 'gravity'\n")
    hits = queries(ast.parse(src), names())
    assert [line for line, _ in hits] == [1, 2, 3, 4, 5, 6, 7]


def test_registry_keys_are_those_of_the_files() -> None:
    """The registry's file keys are the conventions' (docs/conventions.md), in file order."""
    from mocap_calib.core.model.parameters import COMPARED, PER_TAKE

    assert [p.value_key for p in PARAMETERS.values()] == [
        ("gyro_bias",), ("accel_bias",), ("T_marker_imu", "rotation_wxyz"),
        ("T_marker_imu", "translation"), ("gravity_in_mocap",), ("time_offset",)]
    assert [p.sigma_key for p in PARAMETERS.values()] == [
        "gyro_bias", "accel_bias", "rotation", "translation", "gravity_in_mocap", "time_offset"]
    assert [(p.dim, p.value_dim) for p in PARAMETERS.values()] == [
        (3, 3), (3, 3), (3, 4), (3, 3), (2, 3), (1, 1)]
    assert [p.symbol for p in COMPARED] == ["R_MI", "p_MI", "t_d"]
    assert {p.name for p in PER_TAKE} == {"gyro_bias", "accel_bias", "time_offset"}
