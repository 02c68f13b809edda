"""Every effect of the registry, alone and all together, through the CLI: simulated, calibrated
with the text and HTML reports and the result YAML, exported to every target, and diagnosed
(with its reports) on a session where it is hidden (an effect with several parameters too,
``accel_size_effect``'s ``r_y`` and ``r_z``).

Effects are handled through their registry entries (``acts_on``, ``param``, ``report_value``),
never by name, so a new effect is walked as soon as it is registered. 50 s sessions keep a walk
to under a minute (marked slow).
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocap_calib.cli.main import main
from mocap_calib.core.model.effects import EFFECTS, Effect
from mocap_calib.workflows.export import ALL_TARGETS, TARGETS

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

WALKS = [[name] for name in EFFECTS] + [list(EFFECTS)]


def cli(*argv: object) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def ok(result: tuple[int, str, str]) -> str:
    code, out, err = result
    assert code == 0, err
    assert "Traceback" not in out + err
    return out


def _reported(result: dict, e: Effect) -> object:
    """The effect's value in the result YAML: the clock offset has its own key, every other
    effect its ``param`` under ``effects``."""
    if e.acts_on == "clock":
        return result["time_offset"]
    return result["effects"][e.name][e.param]


def _same_form(value: object, e: Effect) -> bool:
    """``value`` has the form ``report_value`` gives (numbers, lists, mappings of them)."""
    def shape(x: object) -> object:
        if isinstance(x, dict):
            return {k: shape(v) for k, v in x.items()}
        return np.shape(x)
    return shape(value) == shape(e.report_value(e.zero()))


def _written_or_named(result: dict, effects: list[Effect], target: str, text: str,
                      notes: str, tmp_path: Path) -> None:
    """Every effect is in the exported file (changing its value changes the file) or named
    in a note: never dropped silently."""
    for e in effects:
        if e.acts_on == "clock":
            continue
        neutral = yaml.safe_load(yaml.safe_dump(result))
        changed = e.report_value(e.theta_from_report(_reported(result, e)) + 0.01)
        neutral["effects"][e.name][e.param] = changed
        if e.param in neutral:  # a world variable with a key of its own (|g|)
            neutral[e.param] = changed
        folder = tmp_path / "neutral"
        folder.mkdir(exist_ok=True)
        (folder / "calib.yaml").write_text(yaml.safe_dump(neutral))
        code, _, err2 = cli("export", folder / "calib.yaml", "--to", target, "--out",
                            folder / "out")
        assert code == 0, err2
        same = (folder / "out").read_text().replace(str(folder), str(tmp_path)) == text
        assert not same or f"note: {e.name} is not exported" in notes, (target, e.name, notes)


@pytest.mark.slow
@pytest.mark.parametrize("names", WALKS, ids=[n[0] if len(n) == 1 else "all" for n in WALKS])
def test_effects_through_every_command(names: list[str], tmp_path: Path) -> None:
    effects = [EFFECTS[n] for n in names]
    session = tmp_path / "s"
    ok(cli("simulate", session, "--duration", 50, "--seed", 3,
           *[x for n in names for x in ("-e", n)]))
    model = "+".join(["base", *dict.fromkeys(["time_offset", *names])])
    calib, report, html = tmp_path / "calib.yaml", tmp_path / "r.txt", tmp_path / "r.html"
    ok(cli("calibrate", session, "--model", model, "--report", report, "--html", html,
           "--out", calib, "-q"))
    result = yaml.safe_load(calib.read_text())
    text, page = report.read_text(), html.read_text()
    for e in effects:
        value = _reported(result, e)
        assert value is not None and _same_form(value, e), (e.name, value)
        if e.acts_on != "clock":
            assert f"{e.name}.{e.param}" in text, e.name
        assert e.name in page, e.name
    for target in ALL_TARGETS:
        out = tmp_path / f"export.{target}"
        code, printed, err = cli("export", calib, "--to", target, "--out", out)
        if target in TARGETS:
            assert code == 0 and out.stat().st_size > 0, (target, err)
            _written_or_named(result, effects, target, out.read_text(), printed + err,
                              tmp_path)
        else:  # intrinsics formats take a multipos result: a one-line refusal
            assert code == 2 and "multipos" in err.strip().splitlines()[-1], (target, err)
    # Diagnosis with the effects hidden: found, and in every report.
    out, dhtml = tmp_path / "d.yaml", tmp_path / "d.html"
    # From the base model where the clock offset is hidden (the default start fits one).
    start = ["--start-model", "base"] if "time_offset" in names else []
    printed = ok(cli("diagnose", session, "--candidates", "+".join(names), "--max-steps",
                     len(names), *start, "--out", out, "--html", dhtml, "-q"))
    found = yaml.safe_load(out.read_text())["found"]
    assert found, "no hidden effect found"
    page = dhtml.read_text()
    for name in found:
        assert f"-> added {name}" in printed and name in page
    if len(names) == 1:
        assert found == names
