"""Every step's time is reported: start-up (imports), reading, clock search and stages 1-2, the
position stage, the effect tests, the consistency and the sensitivity steps, in the log, the
result file and the HTML report; the calibration's steps add up to its total. The same run's
reports list every term of the sigma rule (which one dominates)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from mocap_calib.cli.main import main

pytestmark = pytest.mark.slow  # a full calibration with every check

STEPS = ("startup", "read", "clock_and_stages_1_2", "position_stage", "effect_tests",
         "consistency", "sensitivity")


def test_every_step_is_timed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    sim = tmp_path / "s"
    assert main(["simulate", str(sim), "--seed", "3", "--duration", "40"]) == 0
    out, html = tmp_path / "r.yaml", tmp_path / "r.html"
    assert main(["calibrate", str(sim), "--out", str(out), "--html", str(html)]) == 0
    solver = yaml.safe_load(out.read_text())["solver"]
    steps = solver["step_seconds"]
    assert tuple(steps) == STEPS, steps
    assert all(v >= 0.0 for v in steps.values()), steps
    # The consistency and sensitivity refits are real work on a 40 s session, not zero.
    assert steps["consistency"] > 0.0 and steps["sensitivity"] > 0.0, steps
    inside = sum(steps[k] for k in STEPS[2:])
    assert 0.9 * solver["total_seconds"] <= inside <= solver["total_seconds"] + 0.01, solver
    captured = capsys.readouterr()
    err = captured.err
    # The summary names each term of the sigmas; the HTML has them per axis, as in the file.
    assert "sigma of p_MI (mm, largest axis): statistical" in captured.out
    unc = yaml.safe_load(out.read_text())["uncertainty"]
    assert 'id="uncertainty-table"' in html.read_text() or "uncertainty-table" in html.read_text()
    assert f"{1e3 * unc['p_MI']['total'][1]:.3g}" in html.read_text()
    line = next(x for x in err.splitlines() if "time per step" in x)
    assert "sensitivity" in line and "startup" in line, line
    page = html.read_text()
    assert 'id="steps-table"' in page or "steps-table" in page
    assert "solver/step_seconds/sensitivity" in page
