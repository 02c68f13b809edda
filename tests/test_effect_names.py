"""Effects act through their registry properties (``Effect.acts_on``, ``sensor``,
``about_identity``, ``limits``, ``range_sigma``), never by name: no module outside the registry
asks a model for an effect by name, compares a name with an effect's, or tests a name's suffix.

The check walks every module's syntax tree for an effect name of the registry (or a suffix
shared by several, such as ``scale_misalignment``) used as a query: the argument of
``has``/``with_effect``/``endswith``/``startswith``, an ``EFFECTS[...]`` index, or an operand of
``==``, ``!=``, ``in``, ``not in`` (also inside a tuple, list or set). A name as a dict key or
a result-file field (``d["time_offset"]``) is data, not a query, and is left alone.
"""

from __future__ import annotations

import ast
from pathlib import Path

from mocap_calib.core.model.effects import EFFECTS

PACKAGE = Path(__file__).resolve().parents[1] / "mocap_calib"

#: Modules allowed to query effects by name, and why.
ALLOWED = {
    # The registry itself: names are what it maps to properties.
    "mocap_calib/core/model/effects.py",
}

_QUERY_CALLS = {"has", "with_effect", "endswith", "startswith", "removesuffix", "removeprefix"}


def _names() -> set[str]:
    names = set(EFFECTS)
    parts = [n.split("_") for n in EFFECTS]
    # Suffixes of two or more words shared by several effects ("scale_misalignment").
    for p in parts:
        for k in range(1, len(p) - 1):
            suffix = "_".join(p[k:])
            if sum(n.endswith(suffix) for n in EFFECTS) > 1:
                names.add(suffix)
    return names


def _strings(node: ast.AST) -> list[ast.Constant]:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node]
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return [c for e in node.elts for c in _strings(e)]
    return []


def queries(tree: ast.AST, names: set[str]) -> list[tuple[int, str]]:
    """(line, name) of every effect name used as a query in ``tree``."""
    found: list[ast.Constant] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) \
                and node.func.attr in _QUERY_CALLS:
            found += [c for a in node.args for c in _strings(a)]
        elif isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name) \
                and node.value.id == "EFFECTS":
            found += _strings(node.slice)
        elif isinstance(node, ast.Compare) and all(
                isinstance(op, (ast.Eq, ast.NotEq, ast.In, ast.NotIn)) for op in node.ops):
            for side in (node.left, *node.comparators):
                found += _strings(side)
    return sorted({(c.lineno, c.value) for c in found if c.value in names})


def test_no_module_queries_an_effect_by_name() -> None:
    names = _names()
    assert "scale_misalignment" in names and "time_offset" in names
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = str(path.relative_to(PACKAGE.parent))
        if rel in ALLOWED:
            continue
        for line, name in queries(ast.parse(path.read_text()), names):
            bad.append(f"{rel}:{line}: {name!r}")
    assert not bad, ("effects special-cased by name (use Effect properties: acts_on, sensor, "
                     "about_identity, of_kind/of_term, Model.timed):\n" + "\n".join(bad))


def test_the_check_catches_each_form() -> None:
    """The walker sees every query form (so a pass above is not a blind spot)."""
    src = ("m.has('time_offset')\nm.with_effect('time_offset')\nn.endswith('scale_misalignment')\n"
           "EFFECTS['accel_delay']\nx == 'gravity_magnitude'\n'clock_drift' in cov\n"
           "n in ('gyro_bias_drift', 'other')\nd = {'time_offset': 1}\nv = d['time_offset']\n")
    hits = queries(ast.parse(src), _names())
    assert [line for line, _ in hits] == [1, 2, 3, 4, 5, 6, 7]


def test_registry_properties_cover_what_names_did() -> None:
    """Properties that replaced the name tests agree with the registry's documented forms."""
    from mocap_calib.core.model.effects import CLOCK_OFFSET, GRAVITY_MAGNITUDE, Model, of_term

    assert {e.name for e in EFFECTS.values() if e.about_identity} == {
        "gyro_scale_misalignment", "accel_scale_misalignment"}
    assert (CLOCK_OFFSET.acts_on, GRAVITY_MAGNITUDE.acts_on) == ("clock", "gravity")
    assert of_term("gyro", "f").param == "g_sensitivity"
    m = Model.parse("base+gravity_magnitude+accel_delay+time_offset")
    assert m.timed and not Model.parse("base+accel_delay").timed
    assert [e.name for e in m.world_units()] == ["time_offset", "gravity_magnitude"]
