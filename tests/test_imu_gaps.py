"""IMU dropouts as flight-controller logs have them: found by the one gap rule, trimmed at the
log's start, bridged or split, refused only when they leave too little; every command runs
over them (calibrate, groundtruth, allan, multipos; drift refuses a segment across one)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from test_calibrate import errors_vs_truth

from mocap_calib.cli.main import main
from mocap_calib.core.intrinsics.allan import characterise_noise
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.core.policy import IMU_BRIDGE_MAX_S
from mocap_calib.core.prepare.gaps import find_imu_gaps
from mocap_calib.errors import ObservabilityError
from mocap_calib.sim.flight import SimConfig, simulate_flight
from mocap_calib.sim.static import simulate_static

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

#: The gap pattern of real PX4 logs: dozens of 12-161 ms dropouts (one right after the first
#: sample), one 0.5 s and one 3 s stall.
PX4_LIKE = {"imu_dropouts": [36], "imu_stalls": [0.5, 3.0]}


def _times(n: int = 2000, rate: float = 200.0) -> np.ndarray:
    return np.arange(n) / rate


def test_gaps_are_found_bridged_split_and_the_start_trimmed() -> None:
    t = _times()
    keep = np.ones(len(t), bool)
    keep[1:9] = False  # 40 ms after the first sample: logger start
    keep[300:310] = False  # 55 ms: bridged
    keep[1000:1200] = False  # 1 s: splits
    trim, gaps = find_imu_gaps(t[keep])
    assert trim == 1
    assert gaps.count == 2
    np.testing.assert_allclose(gaps.lengths, [0.055, 1.005], atol=1e-9)
    assert list(gaps.split) == [False, True]
    d = gaps.to_dict()
    assert d["bridged"] == 1 and d["split"] == 1 and d["segments"] == 2
    assert d["trimmed_samples"] == 1
    assert "split the session into 2 segments" in gaps.summary()
    # Spans across a gap (or within its margin of three samples) are not clear.
    t_k = t[keep][trim:]
    assert list(gaps.spans_clear([1.0, 1.49, 1.4, 2.0], [1.4, 1.6, 1.485, 5.2])) == [
        True, False, False, False]
    assert gaps.spans_clear([7.0], [9.9]).all() and t_k[-1] > 9.9


def test_a_step_of_three_median_steps_or_less_is_no_gap() -> None:
    t = _times()
    keep = np.ones(len(t), bool)
    keep[500:502] = False  # 15 ms = 3 steps: jitter / dropped samples the interpolant bridges
    _, gaps = find_imu_gaps(t[keep])
    assert gaps.count == 0


def test_gaps_over_most_of_the_log_are_refused_with_time_row_and_fix() -> None:
    t = _times(4000)
    keep = (np.arange(len(t)) % 400) < 150  # 0.75 s of data, then a 1.25 s gap
    with pytest.raises(ObservabilityError) as err:
        find_imu_gaps(t[keep], "imu.csv")
    msg = str(err.value)
    assert msg.startswith("imu.csv: gaps cover") and "data row" in msg and "re-record" in msg


def test_a_log_with_no_stretch_long_enough_is_refused() -> None:
    t = _times(4000)
    keep = (np.arange(len(t)) % 300) < 200  # 1 s of data, 0.5 s gap: less than 2 s each
    with pytest.raises(ObservabilityError, match="no stretch of the IMU log between gaps is 2 s"):
        find_imu_gaps(t[keep], "imu.csv")


def _calibrate(effects: dict) -> tuple:
    sim = simulate_flight(SimConfig(seed=31, duration=90.0,
                                    effects={"time_offset": [0.006], **effects}))
    return calibrate(sim.imu, sim.mocap, CalibrationOptions(segments=0, sensitivity=False)), sim


@pytest.mark.slow
def test_px4_like_gaps_calibrate_nearly_as_well_as_none() -> None:
    """Errors within about twice those of the same session without
    gaps (rotation, translation, clock offset), sigmas that still cover them, and the result
    saying what the gaps were."""
    clean, sim0 = _calibrate({})
    gappy, sim = _calibrate(PX4_LIKE)
    err0, _ = errors_vs_truth(clean, sim0.truth)
    err, z = errors_vs_truth(gappy, sim.truth)
    assert len(sim.truth["simulation"]["imu_gaps_start_length_s"]) == 39
    for k in ("rotation_deg", "translation_m", "time_offset_s"):
        # Twice the gap-free error, or what chance gives at this sigma (the clean error can be
        # small by luck).
        assert err[k] <= max(2.0 * err0[k], 2.5 * {"rotation_deg": 0.004, "translation_m": 2e-4,
                                                   "time_offset_s": 1.5e-5}[k]), (k, err, err0)
    assert max(z.values()) < 3.5, z
    g = gappy.imu_gaps
    assert g.trimmed_samples >= 1 and g.split == 2 and g.segments == 3
    assert g.count >= 30 and abs(g.longest_s - 3.0) < 0.02
    assert g.bridged == g.count - 2


@pytest.mark.slow
def test_cli_log_and_result_file_say_what_gaps_there_were(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    out = tmp_path / "s"
    assert main(["simulate", str(out), "--seed", "5", "--duration", "60", "-e",
                 "time_offset=0.004", "-e", "imu_dropouts=20", "-e", "imu_stalls=0.8",
                 "-e", "mocap_dropouts=4"]) == 0
    capsys.readouterr()
    assert main(["calibrate", str(out), "--out", str(tmp_path / "c.yaml"), "--segments",
                 "0"]) == 0
    err = capsys.readouterr().err
    line = next(ln for ln in err.splitlines() if "IMU gaps:" in ln)
    assert "bridged" in line and "split the session into 2 segments" in line
    d = yaml.safe_load((tmp_path / "c.yaml").read_text())
    assert d["imu_gaps"]["split"] == 1 and d["imu_gaps"]["count"] >= 18
    assert main(["groundtruth", str(out), "--calibration", str(tmp_path / "c.yaml"), "--out",
                 str(tmp_path / "gt.csv"), "-q"]) == 0
    side = yaml.safe_load((tmp_path / "gt.yaml").read_text())
    assert any(abs(g["length_s"] - 0.8) < 0.02 for g in side["imu_gaps"])


def test_an_imu_gap_inside_a_mocap_gap_is_bridged() -> None:
    sim = simulate_flight(SimConfig(seed=8, duration=60.0, effects={"time_offset": [0.003]}))
    imu, mocap = sim.imu, sim.mocap
    hole_m = (mocap.t > 30.0) & (mocap.t < 30.6)
    hole_i = (imu.t > 30.2) & (imu.t < 30.35)
    res = calibrate(imu.select(~hole_i), mocap.select(~hole_m),
                    CalibrationOptions(segments=0, sensitivity=False))
    err, z = errors_vs_truth(res, sim.truth)
    assert res.imu_gaps.count == 1 and max(z.values()) < 4.0, (err, z)


def test_cropping_comes_before_the_gap_rule(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """A log whose second half is mostly gaps calibrates on its first half: --end cuts first."""
    out = tmp_path / "s"
    assert main(["simulate", str(out), "--seed", "6", "--duration", "80", "-e",
                 "time_offset=0.004"]) == 0
    imu_csv = out / "mav0" / "imu0" / "data.csv"
    lines = imu_csv.read_text().splitlines()
    body = lines[1:]
    keep = [r for i, r in enumerate(body) if i < 6000 or (i % 100) < 5]
    imu_csv.write_text("\n".join([lines[0], *keep]) + "\n")
    capsys.readouterr()
    assert main(["calibrate", str(out), "--out", str(tmp_path / "c.yaml"), "-q"]) == 3
    assert "gaps cover" in capsys.readouterr().err
    assert main(["calibrate", str(out), "--end", "29", "--segments", "0", "--out",
                 str(tmp_path / "c.yaml"), "-q"]) == 0


def test_allan_over_gap_free_stretches_matches_the_whole_log() -> None:
    imu, truth = simulate_static(seed=4, duration_s=1800.0, rate_hz=100.0)
    keep = np.ones(len(imu), bool)
    rng = np.random.default_rng(0)
    for start in rng.integers(1000, len(imu) - 1000, 25):
        keep[start:start + int(rng.integers(2, 16))] = False  # 20-160 ms
    keep[90000:90300] = False  # a 3 s stall
    whole = characterise_noise(imu, require_random_walk=False)
    gappy = characterise_noise(imu.select(keep), require_random_walk=False)
    for a, b in ((gappy.gyroscope, whole.gyroscope), (gappy.accelerometer, whole.accelerometer)):
        np.testing.assert_allclose(a.noise_density, b.noise_density, rtol=0.03)
    # And against the simulator's truth.
    np.testing.assert_allclose(gappy.gyroscope.noise_density.mean(),
                               truth["gyroscope_noise_density"], rtol=0.1)


def test_drift_refuses_a_segment_across_an_imu_gap(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s"
    assert main(["simulate", str(out), "--seed", "3", "--duration", "30", "-e",
                 "imu_stalls=1.0"]) == 0
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    start, length = truth["simulation"]["imu_gaps_start_length_s"][0]
    assert length > IMU_BRIDGE_MAX_S
    capsys.readouterr()
    code = main(["drift", "--imu", str(out / "mav0" / "imu0" / "data.csv"), "--mocap",
                 str(out / "mav0" / "vicon0" / "data.csv"), "--calibration",
                 str(out / "truth.yaml"), "--segment-start", f"{start - 3:.3f}", "--segment-end",
                 f"{start + length + 3:.3f}"])
    err = capsys.readouterr().err
    assert code == 2 and "IMU gap" in err
    assert "choose --segment-start/--segment-end between the gaps" in err


def test_imu_samples_select_keeps_the_origin() -> None:
    imu = ImuSamples(_times(10), np.zeros((10, 3)), np.zeros((10, 3)), 123, "x")
    sub = imu.select(np.arange(10) > 2)
    assert sub.time_origin_ns == 123 and sub.t[0] == pytest.approx(0.015)


def test_local_derivative_is_exact_on_a_quadratic_and_never_spans_a_gap() -> None:
    """The local quadratic fit (compiled) recovers a quadratic's value and slope exactly on
    uneven spacing; fits at the ends or across a gap are marked invalid."""
    from mocap_calib.core.prepare.session import local_derivative

    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.008, 0.012, 400))
    t[200:] += 0.3  # a gap
    y = np.column_stack([1.0 + 2.0 * t - 0.7 * t**2, -3.0 * t**2, np.full_like(t, 4.0)])
    dy = np.column_stack([2.0 - 1.4 * t, -6.0 * t, np.zeros_like(t)])
    value, deriv, valid = local_derivative(t, y, 4, 0.05)
    expect = np.ones(400, bool)
    expect[:4] = expect[-4:] = False
    expect[196:204] = False  # windows that would reach over the gap
    np.testing.assert_array_equal(valid, expect)
    np.testing.assert_allclose(value[valid], y[valid], atol=1e-9)
    np.testing.assert_allclose(deriv[valid], dy[valid], atol=1e-7)
