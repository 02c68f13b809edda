"""``diagnose`` with several takes of one rig (repeated --imu/--mocap pairs or mav0 folders, as
``calibrate``): every fit is joint (shared effects, each take its own clock offset and biases);
an effect is found only when it holds across the takes, and the report says per take whether
its own data show it."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from test_html_report import Page

from mocap_calib.cli.main import main
from mocap_calib.io.formats.euroc import write_mav0
from mocap_calib.sim.flight import SimConfig, simulate_flight

RIG = 91
TAKES = ((31, 0.004), (32, -0.009))  # (seed, clock offset): one rig, two power cycles


def _takes(tmp: Path, effects: dict) -> list[str]:
    """Two takes of one simulated rig written as mav0 folders; the CLI's pairs for them."""
    args = []
    for i, (seed, td) in enumerate(TAKES):
        sim = simulate_flight(SimConfig(seed=seed, duration=40.0, rig_seed=RIG,
                                        effects={"time_offset": [td], **effects}))
        mav0 = write_mav0(tmp / f"take{i}", sim.imu, sim.mocap)
        args += ["--imu", str(mav0 / "imu0" / "data.csv"),
                 "--mocap", str(mav0 / "vicon0" / "data.csv")]
    return args


def _diagnose(tmp: Path, args: list[str], *more: str) -> dict:
    out = tmp / "report.yaml"
    assert main(["diagnose", *args, "--start-model", "base+time_offset", "--out", str(out),
                 "-q", *more]) == 0
    return yaml.safe_load(out.read_text())


@pytest.mark.slow
def test_an_effect_both_takes_have_is_found_with_each_takes_evidence(tmp_path: Path) -> None:
    html = tmp_path / "report.html"
    d = _diagnose(tmp_path, _takes(tmp_path, {"accel_delay": [0.004]}), "--html", str(html))
    assert d["found"] == ["accel_delay"]
    added = next(s["added"] for s in d["steps"] if "added" in s)
    assert abs(added["accel_delay"] - 0.004) < 3 * added["sigma"] + 1e-5
    per_take = added["takes"]
    assert [t["take"] for t in per_take] == [1, 2]
    for t in per_take:
        assert t["evidence"] and t["log10_p"] < d["test"]["threshold_log10_p"]
        assert abs(t["value"] - 0.004) < 3 * t["sigma"] + 1e-5
    # Each take alone is less sure than both together.
    assert added["sigma"] < min(t["sigma"] for t in per_take)
    # The HTML page has the same per-take evidence, keyed to the report's values.
    page = Page(html.read_text(encoding="utf-8"))
    step = next(i for i, s in enumerate(d["steps"]) if "added" in s)
    cells = {c["data-key"]: c for c in page.cells}
    for j in range(2):
        assert cells[f"steps/{step}/added/takes/{j}/evidence"]["data-value"] == "true"
        assert float(cells[f"steps/{step}/added/takes/{j}/value"]["data-value"]) == \
            per_take[j]["value"]
    # The final calibration is the joint one: one accel_delay, each take's own clock offset.
    final = d["final_calibration"]
    assert [round(t["time_offset"], 4) for t in final["takes"]] == [td for _, td in TAKES]
    # The final calibration's residuals and trajectory are drawn for each take.
    text = html.read_text(encoding="utf-8")
    for sec in ("take2-sec-residuals", "take2-sec-trajectory"):
        assert f'id="{sec}"' in text
    assert "Final calibration: Take 1: " in text and "Final calibration: Take 2: " in text


@pytest.mark.slow
def test_two_takes_without_an_effect_find_none(tmp_path: Path) -> None:
    d = _diagnose(tmp_path, _takes(tmp_path, {}))
    assert d["found"] == [] and not [x for x in d["implausible"]
                                     if not x.get("takes_disagree")]
    assert len(d["final_calibration"]["takes"]) == 2


def test_unequal_pairs_are_refused_in_one_line(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["diagnose", "--imu", "a.csv", "--mocap", "a.csv", "--imu", "b.csv",
                 "--out", str(tmp_path / "r.yaml")])
    err = capsys.readouterr().err
    assert code == 2 and "2 --imu and 1 --mocap given" in err and err.count("\n") == 1


@pytest.mark.slow
def test_model_auto_with_two_takes_keeps_what_every_take_shows(tmp_path: Path) -> None:
    """``--model auto`` over two takes: one joint diagnosis, an effect kept only when each
    take's own test shows it, the result calibrated jointly with it."""
    out = tmp_path / "auto.yaml"
    args = _takes(tmp_path, {"accel_delay": [0.004]})
    assert main(["calibrate", *args, "--model", "auto", "--out", str(out), "-q"]) == 0
    a = yaml.safe_load(out.read_text())
    assert "accel_delay" in a["model"].split("+")
    assert abs(a["effects"]["accel_delay"]["accel_delay"] - 0.004) < 0.5e-3
    assert [("accel_delay" in x) for x in a["model_selection"]["found_per_take"]] == [True, True]
    assert len(a["takes"]) == 2
