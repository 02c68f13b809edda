"""Attitude-drift check: calibrated gyro integration drifts less, by the expected amount."""

from __future__ import annotations

import numpy as np
import pytest

from mocap_calib.core.intrinsics.attitude_drift import (
    GyroCalibration,
    attitude_drift_check,
    roll_pitch,
)
from mocap_calib.core.intrinsics.multipos import calibrate_multipos
from mocap_calib.core.model import so3
from mocap_calib.core.model.types import ImuSamples, NoiseModel
from mocap_calib.errors import InputError, ObservabilityError
from mocap_calib.sim.multipos import simulate_multipos
from mocap_calib.sim.static import simulate_static

SILENT = NoiseModel(gyroscope_noise_density=0.0, gyroscope_random_walk=0.0,
                    accelerometer_noise_density=0.0, accelerometer_random_walk=0.0)
DOWN = np.array([0.0, 0.0, -1.0])


def _level_static(bias: np.ndarray, noise: NoiseModel, duration: float = 130.0,
                  seed: int = 0) -> tuple[ImuSamples, dict]:
    """A level static log whose gyro bias is exactly ``bias``."""
    imu, truth = simulate_static(seed, duration, 200.0, noise=noise, tilt_deg=0.0)
    gyro = imu.gyro - np.asarray(truth["gyro_bias_initial"]) + bias
    return ImuSamples(imu.t, gyro, imu.accel, imu.time_origin_ns, imu.source), truth


def test_static_segment_matches_the_analytic_drift() -> None:
    b = np.array([2e-4, -3e-4, 5e-4])  # rad/s
    imu, truth = _level_static(b, SILENT)
    cal = {"gyro_bias": b.tolist(), "accel_bias": truth["accel_bias_initial"]}
    res = attitude_drift_check(imu, 10.0, 70.0, cal)
    T = res.duration
    assert T == pytest.approx(60.0)
    # Exact: the raw integration turns at the constant rate b, so the body "up" vector is
    # Exp(-b T) z; roll and pitch of that attitude are the drift.
    R_end = so3.rotation_between(so3.exp(-b * T) @ np.array([0.0, 0.0, 1.0]), -DOWN)
    roll, pitch = np.degrees(roll_pitch(R_end, DOWN))
    assert res.roll_drift_raw_deg == pytest.approx(roll, abs=1e-6)
    assert res.pitch_drift_raw_deg == pytest.approx(pitch, abs=1e-6)
    # To first order: roll drift = b_x T, pitch drift = b_y T, tilt = |b_xy| T; the
    # second-order term (|b| T)^2 / 2 bounds the difference.
    second = np.degrees(0.5 * (np.linalg.norm(b) * T) ** 2)
    assert res.roll_drift_raw_deg == pytest.approx(np.degrees(b[0] * T), abs=second)
    assert res.pitch_drift_raw_deg == pytest.approx(np.degrees(b[1] * T), abs=second)
    assert res.tilt_drift_raw_deg == pytest.approx(np.degrees(np.hypot(b[0], b[1]) * T),
                                                   abs=second)
    assert abs(res.tilt_drift_cal_deg) < 1e-9 and res.reduction == pytest.approx(1.0)
    assert res.initial_source == res.reference_source == "accel"


def test_noisy_static_segment_with_an_estimated_bias() -> None:
    """Bias estimated on [0, 60] s, checked on [70, 370] s: the calibrated drift is at the
    angle-random-walk level, the raw one at bias x time."""
    # White noise only: with the random walk the bias would not stay the "known" one.
    noise = NoiseModel(gyroscope_random_walk=0.0, accelerometer_random_walk=0.0)
    b = np.array([3e-4, -2e-4, 1e-4])
    imu, truth = _level_static(b, noise, duration=380.0, seed=1)
    b_est = imu.gyro[imu.t < 60.0].mean(axis=0)
    cal = GyroCalibration(b_est, accel_bias=np.asarray(truth["accel_bias_initial"]))
    t = imu.t
    series = (t[::50], np.broadcast_to(np.eye(3), (len(t[::50]), 3, 3)))
    res = attitude_drift_check(imu, 70.0, 370.0, cal, reference_series=series)
    T = res.duration
    expected = np.degrees(np.hypot(b[0], b[1]) * T)
    # 1-sigma per tilt axis: angle random walk over T plus the bias error (60 s mean) times T
    # (0.17 deg and 0.38 deg here).
    N = noise.gyroscope_noise_density
    sigma = np.degrees(np.hypot(N * np.sqrt(T), N / np.sqrt(60.0) * T))
    assert res.tilt_drift_raw_deg == pytest.approx(expected, abs=4 * sigma)
    assert res.tilt_drift_cal_deg < 4 * sigma
    assert res.tilt_drift_cal_deg < 0.3 * res.tilt_drift_raw_deg
    assert res.reduction > 0.7
    # Along the reference series the raw drift grows linearly with time.
    s_t, s_raw = res.series_t, res.series_tilt_raw_deg
    assert s_raw[-1] == pytest.approx(res.tilt_drift_raw_deg, abs=0.05)
    slope = np.polyfit(s_t - s_t[0], s_raw, 1)[0]
    assert slope == pytest.approx(np.degrees(np.hypot(b[0], b[1])), rel=0.1)
    assert res.initial_source == "reference"
    assert set(res.to_dict()["series"]) == {"t", "tilt_raw_deg", "tilt_cal_deg"}


def test_multipos_calibration_reduces_drift_through_rotations() -> None:
    """Calibrate on one session, check on another with the same intrinsics: over a segment
    with 8 rotations (rest to rest) the calibrated roll/pitch drift is far smaller."""
    imu_cal, truth = simulate_multipos(11, n_orientations=20)
    res_cal = calibrate_multipos(imu_cal)
    intr = {k: truth[k] for k in ("accel_matrix", "accel_bias", "gyro_matrix", "gyro_bias")}
    imu, truth2 = simulate_multipos(12, n_orientations=12, **intr)
    iv = np.asarray(truth2["simulation"]["static_intervals_s"])
    t0, t1 = iv[2].mean(), iv[10].mean()
    res = attitude_drift_check(imu, t0, t1, res_cal.to_dict())
    bias_only = attitude_drift_check(imu, t0, t1, {"gyro_bias": res_cal.gyro_bias})
    # What remains: angle random walk and the bias estimate's error over the segment.
    T = res.duration
    sigma = np.degrees(np.hypot(NoiseModel().gyroscope_noise_density * np.sqrt(T),
                                float(np.max(res_cal.gyro_bias_sigma)) * T))
    assert res.tilt_drift_raw_deg > 5.0  # bias ~0.02 rad/s over ~40 s, partly cancelling
    assert res.tilt_drift_cal_deg < 4 * sigma
    assert res.tilt_drift_cal_deg < 0.1 * bias_only.tilt_drift_cal_deg
    assert bias_only.tilt_drift_cal_deg < res.tilt_drift_raw_deg


def test_moving_start_needs_a_given_attitude() -> None:
    imu, truth = simulate_multipos(13, n_orientations=4, init_static_s=10.0)
    iv = np.asarray(truth["simulation"]["static_intervals_s"])
    t_moving = 0.5 * (iv[0, 1] + iv[1, 0])
    cal = {"gyro_bias": truth["gyro_bias"]}
    with pytest.raises(ObservabilityError, match="not at rest .* give a mocap attitude"):
        attitude_drift_check(imu, t_moving, iv[2].mean(), cal)
    res = attitude_drift_check(imu, t_moving, iv[2].mean(), cal, initial_attitude=np.eye(3),
                               reference_attitude=np.eye(3))
    assert res.initial_source == "given"


def test_bad_segment_is_an_input_error() -> None:
    imu, truth = _level_static(np.zeros(3), SILENT, duration=20.0)
    with pytest.raises(InputError, match="t1 must be after t0"):
        attitude_drift_check(imu, 10.0, 5.0, {"gyro_bias": [0.0, 0.0, 0.0]})
    with pytest.raises(InputError, match="no 'gyro_bias'"):
        attitude_drift_check(imu, 1.0, 5.0, {"accel_bias": [0.0, 0.0, 0.0]})
