"""Model diagnosis on simulated sessions where the effect is hidden from the starting model.

One seed per case here, and for the single effects a short list of candidates that includes
the ones most easily confused with it (the suite must stay fast);
`scripts/diagnose_hit_rate.py` measures the hit and false-alarm rates over many seeds with
every candidate.
"""

from __future__ import annotations

import numpy as np
import pytest

from mocap_calib.core.diagnosis.diagnose import DiagnoseOptions, diagnose
from mocap_calib.core.model.effects import CANONICAL_EFFECTS, EFFECTS, Model
from mocap_calib.sim.flight import SimConfig, simulate_flight

#: The base model: where a hidden clock offset is something to find (the default start,
#: ``calibrate``'s model, fits one already).
BASE = Model()

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset


def _check_floor(rep) -> None:
    # A 60 s session's low-band RMS (about 2 x 2 Hz x 60 s = 240 independent samples) scatters
    # by about 4.5 % around the floor: 1.12 is three of those.
    for sensor in ("gyro", "accel"):
        assert rep.final_residuals.ratio(sensor) < 1.12, (
            f"{sensor} residual {rep.final_residuals.ratio(sensor):.3f} x the noise floor")


#: Candidates that most easily take another effect's place.
CONFUSABLE = ("time_offset", "clock_drift", "accel_delay", "gyro_scale_misalignment",
              "accel_scale_misalignment", "gyro_g_sensitivity")


#: A trend the continuous bias walk follows leaves the low band at the noise floor, so the
#: refit cannot show in the measurement domain (its score test is significant: log10 p -4.5
#: at 4e-3 m/s^3 on this seed); docs/validation.md, the diagnosis's bias trends.
TREND_HIDDEN_BY_WALK = pytest.mark.xfail(
    strict=True, reason="an accelerometer trend the bias walk follows does not show in the "
    "low-band residual")


@pytest.mark.parametrize("effect", [pytest.param(e, marks=TREND_HIDDEN_BY_WALK)
                                    if e == "accel_bias_drift" else e
                                    for e in CANONICAL_EFFECTS])
def test_hidden_effect_is_named_first(effect: str) -> None:
    sim = simulate_flight(SimConfig(seed=500 + CANONICAL_EFFECTS.index(effect), duration=60.0,
                                    effects={effect: None}))
    cands = tuple(dict.fromkeys((effect, *CONFUSABLE)))
    start = BASE if effect == "time_offset" else DiagnoseOptions().start_model
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(start_model=start, candidates=cands))
    assert rep.found and rep.found[0] == effect, f"found {rep.found}"
    assert rep.found == [effect], f"false alarm after the hidden effect: {rep.found}"
    _check_floor(rep)
    # The named effect's parameters match the simulator's truth.
    eff = EFFECTS[effect]
    truth = sim.truth["effects"][effect][eff.param]
    added = rep.steps[0].added_params
    sigma = rep.steps[0].added_sigma
    flat = (lambda v: eff.theta_from_report(v)) if eff.acts_on == "size" else np.asarray
    err = np.abs(np.asarray(flat(added), float) - np.asarray(flat(truth), float))
    assert np.all(err <= 5.0 * np.asarray(flat(sigma), float) + 1e-12), (added, truth, sigma)


def test_no_hidden_effect_says_none() -> None:
    sim = simulate_flight(SimConfig(seed=600, duration=90.0))
    opts = DiagnoseOptions()
    rep = diagnose(sim.imu, sim.mocap, opts)
    assert rep.found == [] and rep.verdict == "none"
    _check_floor(rep)
    # Every candidate the starting model lacks was scored and none passed; only those the
    # score test finds significant are refitted.
    cands = rep.steps[0].candidates
    assert {c.effect for c in cands} == set(CANONICAL_EFFECTS) - set(opts.start_model.effects)
    refitted = {c.effect for c in cands if not np.isnan(c.confirm_statistic)}
    assert refitted <= {c.effect for c in cands if c.log10_p < rep.threshold_log10_p}


def test_two_hidden_effects_are_both_found() -> None:
    pair = ("gyro_scale_misalignment", "time_offset")
    sim = simulate_flight(SimConfig(seed=601, duration=90.0, effects={e: None for e in pair}))
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(start_model=BASE))
    assert set(rep.found) == set(pair), f"found {rep.found}"
    _check_floor(rep)
    # One refit per effect added (two when a clock offset is weighed against the first), not
    # one per candidate.
    for step in rep.steps[:-1]:
        assert sum(not np.isnan(c.confirm_statistic) for c in step.candidates) <= 2


def test_the_checks_run_on_the_answer_only(monkeypatch) -> None:
    """The starting fit gets calibrate's checks (effect tests, consistency, sensitivity,
    plausibility) only when it is the answer; with an effect found, only the final
    calibration gets them. When nothing is found the answer is what ``calibrate`` gives."""
    import mocap_calib.core.pipeline.calibrate as cal
    from mocap_calib.core.options import CalibrationOptions

    judged: list[str] = []
    real = cal.judge

    def judge(r, *args, **kwargs):
        judged.append(r.model)
        return real(r, *args, **kwargs)

    monkeypatch.setattr(cal, "judge", judge)
    sim = simulate_flight(SimConfig(seed=4, duration=60.0, effects={"time_offset": [0.006]}))
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(start_model=BASE,
                                                       candidates=("time_offset",
                                                                   "accel_delay")))
    assert rep.found == ["time_offset"] and judged == ["base+time_offset"]
    judged.clear()
    # The default start is calibrate's model: with nothing to add, the answer is its own.
    timed = CalibrationOptions().model
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(candidates=("accel_delay",)))
    assert rep.found == [] and judged == ["base+time_offset"]
    ref = cal.calibrate(sim.imu, sim.mocap, CalibrationOptions(model=timed))
    got = rep.final
    for p, e in ref.estimates.items():
        np.testing.assert_array_equal(got.estimates[p].value, e.value, err_msg=p.name)
        np.testing.assert_array_equal(got.estimates[p].sigma, e.sigma, err_msg=p.name)
    assert got.notes == ref.notes and got.effect_tests == ref.effect_tests


def test_the_final_calibration_is_calibrates_with_the_model_found() -> None:
    """With an effect found, the final calibration reuses the starting fit's clock and
    stages 1-2 (they do not depend on the effects added): its answer is exactly what
    ``calibrate`` gives with the model found."""
    from mocap_calib.core.options import CalibrationOptions
    from mocap_calib.core.pipeline.calibrate import calibrate

    sim = simulate_flight(SimConfig(seed=5, duration=60.0, effects={"accel_delay": [0.004]}))
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(candidates=("accel_delay",
                                                                   "gravity_magnitude")))
    assert rep.found == ["accel_delay"]
    ref = calibrate(sim.imu, sim.mocap, CalibrationOptions(model=Model.parse(rep.final_model)))
    got = rep.final
    for p, e in ref.estimates.items():
        np.testing.assert_array_equal(got.estimates[p].value, e.value, err_msg=p.name)
        np.testing.assert_array_equal(got.estimates[p].sigma, e.sigma, err_msg=p.name)
    assert got.effects == ref.effects and got.notes == ref.notes


def test_report_round_trips_through_yaml(tmp_path) -> None:
    from mocap_calib.io.yaml_io import load_yaml, save_yaml

    sim = simulate_flight(SimConfig(seed=602, duration=40.0, effects={"time_offset": [0.006]}))
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(start_model=BASE,
                                                       candidates=("time_offset",
                                                                   "gravity_magnitude")))
    save_yaml(tmp_path / "r.yaml", rep.to_dict())
    d = load_yaml(tmp_path / "r.yaml")
    assert d["found"] == ["time_offset"]
    step = d["steps"][0]
    assert step["added"]["effect"] == "time_offset"
    assert step["added"]["time_offset"] == pytest.approx(0.006, abs=2e-4)
    assert step["residuals"]["gyro_ratio"] > step["residuals_after"]["gyro_ratio"]
    # In frequency too: the missing clock offset shows as excess power in the low bands.
    bands = step["residuals"]["power_over_floor_by_band"]["gyro"]
    assert max(bands["0.5-2 Hz"]) > 3.0
    after = step["residuals_after"]["power_over_floor_by_band"]["gyro"]
    assert max(after["0.5-2 Hz"]) < 2.0
    assert d["final_calibration"]["time_offset"] == pytest.approx(0.006, abs=2e-4)
    # Typed and versioned: the file reads back into a report that writes the same data.
    from mocap_calib.core.diagnosis.diagnose import DiagnoseReport
    from mocap_calib.core.versioned import KindError

    assert (d["kind"], d["version"]) == ("diagnosis", 2)
    back = DiagnoseReport.from_dict(d)
    assert back.found == ["time_offset"]
    assert load_yaml(save_yaml(tmp_path / "r2.yaml", back.to_dict())) == d
    with pytest.raises(KindError, match="newer"):
        DiagnoseReport.from_dict({**d, "version": 3})


def test_cli_diagnose_bad_options_exit_2(capsys, tmp_path) -> None:
    from mocap_calib.cli.main import main
    from mocap_calib.workflows.simulate import simulate_to_folder

    simulate_to_folder(tmp_path / "s", seed=1, duration=20.0)
    for args in (["--alpha", "2"], ["--start", "base+warp_drive"], ["--max-steps", "0"]):
        code = main(["diagnose", str(tmp_path / "s"), "--out", str(tmp_path / "r.yaml"), *args])
        err = capsys.readouterr().err
        assert code == 2 and err.startswith("error:") and "Traceback" not in err


def test_diagnose_runs_when_the_start_model_leaves_a_parameter_unobservable() -> None:
    """A body that only yaws: the lever arm along the yaw axis is unobservable in every model;
    the diagnosis must still run (from the solver's values, not the result's nulls)."""
    from test_calibrate import yaw_only_session

    imu, mocap = yaw_only_session()
    rep = diagnose(imu, mocap, DiagnoseOptions(candidates=("time_offset", "gravity_magnitude")))
    assert rep.found == []
    assert "translation" in rep.final.unobservable


def test_time_offset_and_clock_drift_are_both_found() -> None:
    sim = simulate_flight(SimConfig(seed=610, duration=60.0,
                                    effects={"time_offset": None, "clock_drift": None}))
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(start_model=BASE, candidates=CONFUSABLE))
    assert set(rep.found) == {"time_offset", "clock_drift"}, rep.found


def test_correlated_mocap_noise_is_not_an_effect() -> None:
    """Mocap noise correlated over 0.3 s and the bias random walk: nothing to name."""
    sim = simulate_flight(SimConfig(seed=611, duration=60.0, mocap_noise_corr=0.3))
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(candidates=CONFUSABLE))
    assert rep.found == [] and rep.unexplained is None, (rep.found, rep.unexplained)


def test_implausible_magnitude_is_listed_not_found() -> None:
    """Accelerometer scale errors of 10 %: significant, but no MEMS part has them."""
    m = [1.1, 0, 0, 0.0, 0.93, 0, 0.0, 0.0, 1.08]
    sim = simulate_flight(SimConfig(seed=612, duration=60.0,
                                    effects={"accel_scale_misalignment": m}))
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(
        candidates=("accel_scale_misalignment", "gravity_magnitude"), max_steps=2))
    assert "accel_scale_misalignment" not in rep.found
    (entry,) = [x for x in rep.implausible if x["effect"] == "accel_scale_misalignment"]
    # The base model cannot fit this session at all (stage 2 leaves 1.3 m/s), so the
    # magnitude its refit finds from there is rough; it is far beyond the plausible 3 % either
    # way.
    reason = entry["reason"]
    assert "scale error up to" in reason and "plausible: 3 %" in reason
    assert float(reason.split("up to ")[1].split(" %")[0]) > 8.0


def test_cause_outside_the_list_is_reported_unexplained() -> None:
    """The accelerometer lags by 6 ms, but that is not among the candidates: nothing is named,
    and the report says the data hold more than the model and the noise, with a signature."""
    sim = simulate_flight(SimConfig(seed=613, duration=60.0, effects={"accel_delay": [0.006]}))
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(
        candidates=("gyro_scale_misalignment", "gravity_magnitude", "gyro_bias_drift")))
    assert rep.found == []
    u = rep.unexplained
    # The noise identification takes the lag's error for accelerometer noise; against the
    # floor at the accelerometer's given density it stands out.
    assert u is not None and any("accel residual" in w for w in u["why"]), u and u["why"]
    assert len(u["accel"]["ratio_per_axis"]) == 3
    assert set(u["accel"]["correlation"]) == {"angular_rate", "angular_acceleration",
                                               "specific_force"}
