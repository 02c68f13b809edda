"""Model diagnosis on simulated sessions where the effect is hidden from the starting model.

One seed per case here (the suite must stay fast); `scripts/diagnose_hit_rate.py` measures the
hit and false-alarm rates over many seeds.
"""

from __future__ import annotations

import numpy as np
import pytest

from mocap_calib.core.diagnosis.diagnose import DiagnoseOptions, diagnose
from mocap_calib.core.model.effects import CANONICAL_EFFECTS, EFFECTS
from mocap_calib.sim.flight import SimConfig, simulate_flight


def _check_floor(rep) -> None:
    for sensor in ("gyro", "accel"):
        assert rep.final_residuals.ratio(sensor) < 1.05, (
            f"{sensor} residual {rep.final_residuals.ratio(sensor):.3f} x the noise floor")


@pytest.mark.parametrize("effect", CANONICAL_EFFECTS)
def test_hidden_effect_is_named_first(effect: str) -> None:
    sim = simulate_flight(SimConfig(seed=500 + CANONICAL_EFFECTS.index(effect), duration=90.0,
                                    effects={effect: None}))
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions())
    assert rep.found and rep.found[0] == effect, f"found {rep.found}"
    assert rep.found == [effect], f"false alarm after the hidden effect: {rep.found}"
    _check_floor(rep)
    # The named effect's parameters match the simulator's truth.
    eff = EFFECTS[effect]
    truth = sim.truth["effects"][effect][eff.param]
    added = rep.steps[0].added_params
    sigma = rep.steps[0].added_sigma
    err = np.abs(np.asarray(added, float) - np.asarray(truth, float))
    assert np.all(err <= 5.0 * np.asarray(sigma, float) + 1e-12), (added, truth, sigma)


def test_no_hidden_effect_says_none() -> None:
    sim = simulate_flight(SimConfig(seed=600, duration=90.0))
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions())
    assert rep.found == [] and rep.verdict == "none"
    _check_floor(rep)
    # Every candidate was tried and none passed.
    assert {c.effect for c in rep.steps[0].candidates} == set(CANONICAL_EFFECTS)


def test_two_hidden_effects_are_both_found() -> None:
    pair = ("gyro_scale_misalignment", "time_offset")
    sim = simulate_flight(SimConfig(seed=601, duration=90.0, effects={e: None for e in pair}))
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions())
    assert set(rep.found) == set(pair), f"found {rep.found}"
    _check_floor(rep)


def test_report_round_trips_through_yaml(tmp_path) -> None:
    from mocap_calib.io.yaml_io import load_yaml, save_yaml

    sim = simulate_flight(SimConfig(seed=602, duration=40.0, effects={"time_offset": [0.006]}))
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(candidates=("time_offset",
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
    assert max(bands["0.5-2 Hz"]) > 10.0
    after = step["residuals_after"]["power_over_floor_by_band"]["gyro"]
    assert max(after["0.5-2 Hz"]) < 2.0
    assert d["final_calibration"]["time_offset"] == pytest.approx(0.006, abs=2e-4)
    # Typed and versioned: the file reads back into a report that writes the same data.
    from mocap_calib.core.diagnosis.diagnose import DiagnoseReport
    from mocap_calib.core.model.versioned import KindError

    assert (d["kind"], d["version"]) == ("diagnosis", 1)
    back = DiagnoseReport.from_dict(d)
    assert back.found == ["time_offset"]
    assert load_yaml(save_yaml(tmp_path / "r2.yaml", back.to_dict())) == d
    with pytest.raises(KindError, match="newer"):
        DiagnoseReport.from_dict({**d, "version": 2})


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
