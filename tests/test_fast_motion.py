"""Motion up to 5 Hz with noise that differs from the assumed model: the calibration stays
accurate and honest, and the diagnosis (10 Hz pose smoothing, 2 Hz comparison band) names no
effect. Every other simulated session moves below 1 Hz with the noise the calibration assumes.

The session: 90 s, rotations and translations with components between 1 and 5 Hz on top of the
flight, IMU noise densities twice the defaults the calibration assumes, mocap noise correlated
over 0.3 s (AR(1)), a 4 ms clock offset.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from scipy.signal import welch
from test_calibrate import errors_vs_truth

from mocap_calib.core.diagnosis.diagnose import DiagnoseOptions, diagnose
from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.errors import InputError
from mocap_calib.sim.flight import SimConfig, SimulatedSession, simulate_flight

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

_DEFAULT = NoiseModel()
#: The true IMU noise: twice the densities the calibration assumes (its defaults).
NOISIER = NoiseModel(gyroscope_noise_density=2 * _DEFAULT.gyroscope_noise_density,
                     accelerometer_noise_density=2 * _DEFAULT.accelerometer_noise_density)
SEED = 700


@cache
def _session() -> SimulatedSession:
    return simulate_flight(SimConfig(seed=SEED, duration=90.0, noise=NOISIER, max_motion_hz=5.0,
                                     mocap_noise_corr=0.3, effects={"time_offset": [0.004]}))


def _band_power(x: np.ndarray, rate: float, lo: float, hi: float) -> float:
    f, p = welch(x - x.mean(axis=0), fs=rate, nperseg=1024, axis=0)
    return float(np.sum(p[(f >= lo) & (f < hi)]))


def test_fast_motion_reaches_5_hz_and_leaves_the_other_draws_alone() -> None:
    cfg = dict(seed=SEED, duration=30.0)
    slow = simulate_flight(SimConfig(**cfg))
    fast = simulate_flight(SimConfig(**cfg, max_motion_hz=5.0))
    # The fast components have their own generator: rig, biases and noise draws are the seed's.
    assert fast.truth["simulation"].pop("max_motion_hz") == 5.0
    assert fast.truth == slow.truth
    assert np.array_equal(fast.gyro_bias_true, slow.gyro_bias_true)
    rate = 200.0
    for a, b in ((fast.imu.gyro, slow.imu.gyro), (fast.imu.accel, slow.imu.accel)):
        # Far more power at 2-5 Hz (the flight's own motion stops near 1 Hz); above, only what
        # the nonlinear kinematics mix up (sum frequencies, < 1 %), and above 11 Hz the noise.
        fast_band = _band_power(a, rate, 2.0, 5.2)
        assert fast_band > 100 * _band_power(b, rate, 2.0, 5.2)
        assert _band_power(a, rate, 5.5, 11.0) < 0.01 * fast_band
        assert _band_power(a, rate, 11.0, 90.0) < 1.1 * _band_power(b, rate, 11.0, 90.0)
    # Physically sane: a few rad/s, below 3 g.
    assert np.max(np.linalg.norm(fast.imu.gyro, axis=1)) < 6.0
    assert np.max(np.linalg.norm(fast.imu.accel, axis=1)) < 3 * 9.81
    for bad in (dict(max_motion_hz=0.5), dict(max_motion_hz=25.0),
                dict(max_motion_hz=5.0, motion="turntable")):
        with pytest.raises(InputError, match="max-motion-hz"):
            simulate_flight(SimConfig(**cfg, **bad))  # type: ignore[arg-type]


#: About three times what seed 700 achieves (0.0120 deg, 0.29 mm, 2.7e-4 rad/s, 5.4e-4 m/s^2,
#: 0.0055 deg, 1.0 us), in the units of test_calibrate.TARGETS. (The point estimate takes the
#: mocap noise as white: this simulator's AR(1) noise, which the estimator used to model
#: exactly, costs it a factor 1-3.5 here; real mocap noise is not AR(1), and on EuRoC V2_03 the
#: white estimate lands 1.4 mm from the ground truth's lever arm, against 8.6 mm.)
FAST_TARGETS = {"rotation_deg": 0.036, "translation_m": 0.9e-3, "gyro_bias": 8e-4,
                "accel_bias": 2.4e-3, "gravity_deg": 0.017, "time_offset_s": 0.025e-3}


def test_calibration_with_fast_motion_and_mismatched_noise() -> None:
    sim = _session()
    res = calibrate(sim.imu, sim.mocap, CalibrationOptions())
    err, z = errors_vs_truth(res, sim.truth)
    for k, limit in FAST_TARGETS.items():
        assert err[k] < limit, f"{k}: error {err[k]:.3g} >= {limit}"
    for k, v in z.items():
        assert v <= 4.0, f"{k}: error is {v:.2f} sigma"
    assert not res.unobservable


def test_diagnosis_names_nothing_on_fast_motion_with_mismatched_noise() -> None:
    """Nothing hidden (the clock offset is in the starting model). The accelerometer's
    residual exceeds the floor of the assumed noise (its true noise is larger), but not so far
    that the report calls it unexplained, and no effect takes the noise's place. With the
    diagnosis's pose smoothing at 3 Hz instead of 10 this test fails (residual reported
    unexplained; on a 60 s session of this kind the ratios go from 1.2-1.3 to 2.2), and it fails
    only with the fast motion. The gyro's doubled density hardly shows in the low band, where
    the mocap's part of its floor dominates: against the floor of the true mocap noise at the
    densities given, the ratios are 1.01 (gyro) and 1.11 (accel); the diagnosis's floor, from
    the identified mocap noise, gives 1.03 and 1.13."""
    sim = _session()
    rep = diagnose(sim.imu, sim.mocap, DiagnoseOptions(start_model=Model(("time_offset",))))
    assert rep.found == [] and rep.verdict == "none", rep.found
    assert rep.unexplained is None, rep.unexplained
    for sensor, low in (("gyro", 0.97), ("accel", 1.05)):
        assert low < rep.final_residuals.ratio(sensor) < 1.5, (
            f"{sensor}: residual {rep.final_residuals.ratio(sensor):.3f} x the noise floor")
