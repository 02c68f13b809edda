"""The accelerometer's noise level from the data (``--accel-noise-from-data``) against the
level a simulated flight was made with, and what it does to the lever arm."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.sim.flight import SimConfig, simulate_flight

#: A drone in flight: the accelerometer 25x its data sheet's density (the EuRoC MAV shows
#: 15-50x against the Vicon), a Vicon with 0.2 deg attitude and 0.2 mm position noise.
FLYING = replace(NoiseModel(), accelerometer_noise_density=0.05,
                 mocap_rotation_sigma=float(np.radians(0.2)), mocap_position_sigma=2e-4)


@pytest.mark.parametrize("seed", [1, 3])
def test_accel_level_recovers_the_simulated_density(seed: int) -> None:
    sim = simulate_flight(SimConfig(seed=seed, duration=90.0, noise=FLYING,
                                    effects={"time_offset": None}))
    opts = CalibrationOptions(noise=NoiseModel(), sensitivity=False, segments=0,
                              effect_tests=False)
    given = calibrate(sim.imu, sim.mocap, opts)
    found = calibrate(sim.imu, sim.mocap, replace(opts, accel_noise_from_data=True))
    # Started from the data sheet's 2e-3 (25x too low), the likelihood finds the level the
    # session was made with (the estimate of a variance from ~10^5 samples: within 20 %) ...
    assert given.noise.accelerometer_noise_density == pytest.approx(2e-3)
    assert found.noise.accelerometer_noise_density == pytest.approx(0.05, rel=0.2)
    # ... and the lever arm, weighted by it, is within 3 of its (now honest) sigmas.
    p_true = np.asarray(sim.truth["T_marker_imu"]["translation"])
    z = (found.translation - p_true) / found.sigma_translation
    assert np.all(np.abs(z) < 3.0), z


def test_accel_level_stays_where_the_data_sheet_is_right() -> None:
    sim = simulate_flight(SimConfig(seed=2, duration=60.0, effects={"time_offset": None}))
    r = calibrate(sim.imu, sim.mocap, CalibrationOptions(
        sensitivity=False, segments=0, effect_tests=False, accel_noise_from_data=True))
    assert r.noise.accelerometer_noise_density == pytest.approx(
        NoiseModel().accelerometer_noise_density, rel=0.2)


def test_default_run_says_when_the_data_prefer_another_accel_level() -> None:
    """Without the option the densities stay as given, but the verdict says how far the
    data's own level is from them (a one-shot estimate at the solution: the mocap levels there
    absorbed part of the accelerometer's error, so it lands below the joint estimate)."""
    sim = simulate_flight(SimConfig(seed=5, duration=60.0, noise=FLYING,
                                    effects={"time_offset": None}))
    r = calibrate(sim.imu, sim.mocap, CalibrationOptions(segments=0, effect_tests=False))
    assert r.noise.accelerometer_noise_density == pytest.approx(2e-3)
    found = r.sensitivity.accel_noise_density
    assert 5 * 2e-3 < found < 2 * 0.05, found
    assert any("--accel-noise-from-data" in n for n in r.notes), r.notes
    # Where the data sheet is right, nothing is said.
    sim = simulate_flight(SimConfig(seed=5, duration=60.0, effects={"time_offset": None}))
    r = calibrate(sim.imu, sim.mocap, CalibrationOptions(segments=0, effect_tests=False))
    assert r.sensitivity.accel_noise_density == pytest.approx(2e-3, rel=0.5)
    assert not any("--accel-noise-from-data" in n for n in r.notes), r.notes
