"""The effects the data show: every calibration tests the canonical effects its model lacks
(score tests at the solution, listed in order of evidence); ``--model auto`` adds what the
diagnosis finds and gives the diagnose workflow's final answer."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocap_calib.cli.main import main
from mocap_calib.core.model.effects import Model
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.sim.flight import SimConfig, simulate_flight

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

T_D = 0.006


@pytest.mark.parametrize("seed,lag", [(4, 0.004), (9, 0.002)])
def test_the_default_model_names_a_hidden_accel_delay(seed: int, lag: float) -> None:
    sim = simulate_flight(SimConfig(seed=seed, duration=90.0, effects={
        "time_offset": [T_D], "accel_delay": [lag]}))
    opts = CalibrationOptions(segments=0, sensitivity=False)
    r = calibrate(sim.imu, sim.mocap, opts)
    # Named first; a missing delay's misfit can also lift a correlated candidate over the
    # threshold (seed 4: the accelerometer trend, log10 p -3.5), each test being against the
    # model without the delay. With the delay in the model nothing is left to show.
    assert r.effect_tests.shown[0] == "accel_delay", r.effect_tests.shown
    first = r.effect_tests.candidates[0].to_dict()
    assert first["effect"] == "accel_delay" and abs(first["one_step_estimate"] - lag) < 0.5e-3
    assert any("effects the data show" in n and "accel_delay" in n for n in r.notes)
    full = calibrate(sim.imu, sim.mocap,
                     replace(opts, model=Model.parse("base+time_offset+accel_delay")))
    assert full.effect_tests.shown == (), full.effect_tests.candidates[:2]


@pytest.mark.parametrize("seed", [5, 6])
def test_nothing_is_shown_when_nothing_is_missing(seed: int) -> None:
    sim = simulate_flight(SimConfig(seed=seed, duration=90.0, effects={"time_offset": [T_D]},
                                    mocap_noise_corr=0.2 if seed == 6 else 0.0))
    r = calibrate(sim.imu, sim.mocap, CalibrationOptions(segments=0, sensitivity=False))
    assert r.effect_tests.shown == (), r.effect_tests.candidates[:3]
    assert len(r.effect_tests.candidates) == 9  # every canonical effect but time_offset


@pytest.mark.parametrize("seed,lag", [(4, 0.005), (9, 0.002)])
def test_model_auto_recovers_the_delay_and_matches_diagnose(tmp_path: Path, seed: int,
                                                             lag: float) -> None:
    out = tmp_path / "s"
    assert main(["simulate", str(out), "--seed", str(seed), "--duration", "60", "-e",
                 f"time_offset={T_D}", "-e", f"accel_delay={lag}"]) == 0
    assert main(["calibrate", str(out), "--model", "auto", "--out", str(tmp_path / "a.yaml"),
                 "-q"]) == 0
    a = yaml.safe_load((tmp_path / "a.yaml").read_text())
    assert a["model"] == "base+time_offset+accel_delay"
    assert a["model_selection"]["requested"] == "auto"
    assert abs(a["time_offset"] - T_D) < 0.2e-3
    assert abs(a["effects"]["accel_delay"]["accel_delay"] - lag) < 0.5e-3
    assert main(["diagnose", str(out), "--out", str(tmp_path / "d.yaml"), "-q"]) == 0
    d = yaml.safe_load((tmp_path / "d.yaml").read_text())
    assert Model.parse(d["final_model"]).effects == Model.parse(a["model"]).effects
    f = d["final_calibration"]
    for key in ("time_offset",):
        assert abs(f[key] - a[key]) <= 0.5 * a["sigma"][key]
    dp = np.abs(np.array(f["T_marker_imu"]["translation"]) - a["T_marker_imu"]["translation"])
    assert np.all(dp <= 0.5 * np.array(a["sigma"]["translation"]))


def test_effect_tests_on_spread_windows_of_a_long_session(monkeypatch: pytest.MonkeyPatch
                                                          ) -> None:
    """Beyond MAX_TEST_WINDOWS the tests use that many windows spread over the session
    (their cost stays flat): a hidden delay is still named, its estimate as close."""
    from types import SimpleNamespace

    from mocap_calib.core.checks import effect_scores as es

    takes = [SimpleNamespace(windows=SimpleNamespace(count=c)) for c in (500, 220)]
    picked = es._spread(SimpleNamespace(takes=takes))
    assert [len(w) for w in picked] == [167, 73] and picked[0][[0, -1]].tolist() == [0, 499]
    monkeypatch.setattr(es, "MAX_TEST_WINDOWS", 12)  # (8 of 18: too few for the spread test)
    sim = simulate_flight(SimConfig(seed=4, duration=90.0, effects={
        "time_offset": [T_D], "accel_delay": [0.004]}))
    said: list[str] = []
    r = calibrate(sim.imu, sim.mocap, CalibrationOptions(segments=0, sensitivity=False),
                  progress=said.append)
    assert r.solver.windows > 12
    assert any(f"(12 of {r.solver.windows} windows, spread over the session)" in m
               for m in said)
    assert r.effect_tests.windows == r.solver.windows
    assert r.effect_tests.windows_tested == 12
    assert r.effect_tests.shown[0] == "accel_delay", r.effect_tests.shown
    assert abs(r.effect_tests.candidates[0].one_step_estimate - 0.004) < 0.5e-3
