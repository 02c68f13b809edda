"""The noise model identified from the data (``core.position.noise``) against the levels a
simulated session was made with: every level jointly, none absorbing another."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.core.position.engine import PositionProblem, Theta
from mocap_calib.core.position.noise import identify_noise
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.sim.flight import SimConfig, simulate_flight

#: A drone in flight: the accelerometer 25x its data sheet, a Vicon with 0.2 deg attitude and
#: 0.2 mm position noise, all of it correlated (AR(1)) over the session's time constant.
FLYING = replace(NoiseModel(), accelerometer_noise_density=0.05,
                 mocap_rotation_sigma=float(np.radians(0.2)), mocap_position_sigma=2e-4)


def _problems(r: CalibrationResult) -> list[tuple[PositionProblem, Theta]]:
    """The solved position problem of a white-noise fit at the data sheet's densities, as
    the identification meets it after the stage's first round."""
    import gtsam

    pos = r.diagnostics.trace.position
    model = r.diagnostics.trace.model_state.model
    out = []
    for t in pos.takes:
        pp = PositionProblem(t.s, model, pos.noise, t.windows, split=False)
        pp.weights = t.weights
        pp.mocap_axis_scale = pos.axis_scale.copy()
        th = Theta(pos.R_MI, pos.p_MI, pos.g_dir, gtsam.Unit3(pos.g_dir).basis(), pos.g_mag,
                   t.delta, dict(pos.effects), t.knots, t.take.t_mid)
        out.append((pp, th))
    return out


def _given_fit(sim) -> CalibrationResult:
    return calibrate(sim.imu, sim.mocap, CalibrationOptions(
        segments=0, sensitivity=False, effect_tests=False, noise_from_data=False))


@pytest.mark.parametrize("seed", [3, 8])
def test_flight_levels_found_jointly(seed: int) -> None:
    corr = 0.3
    sim = simulate_flight(SimConfig(seed=seed, duration=60.0, noise=FLYING, mocap_noise_corr=corr,
                                    effects={"time_offset": None}))
    r = _given_fit(sim)
    start = r.diagnostics.trace.position.noise
    # The white fit at the data sheet's density blames the accelerometer's error on the
    # mocap: its position level lands an order of magnitude above the true 0.2 mm.
    assert start.mocap_position_sigma > 5 * FLYING.mocap_position_sigma
    ident = identify_noise(_problems(r), start, NoiseModel())
    nz = ident.noise
    assert ident.contradicts and ident.gain > 100 * ident.threshold
    assert nz.accelerometer_noise_density == pytest.approx(0.05, rel=0.15)
    assert nz.mocap_position_sigma == pytest.approx(FLYING.mocap_position_sigma, rel=0.25)
    assert nz.mocap_rotation_sigma == pytest.approx(FLYING.mocap_rotation_sigma, rel=0.15)
    assert nz.mocap_noise_corr_time == pytest.approx(corr, rel=0.5)
    assert nz.mocap_noise_corr_fraction > 0.9  # the simulated noise is all correlated


def test_lab_levels_not_contradicted() -> None:
    """A session made with the densities given and white mocap noise: the data do not
    contradict them, and what the search finds is near them anyway."""
    sim = simulate_flight(SimConfig(seed=4, duration=60.0, effects={"time_offset": None}))
    r = _given_fit(sim)
    ident = identify_noise(_problems(r), r.diagnostics.trace.position.noise, NoiseModel())
    assert not ident.contradicts, (ident.gain, ident.threshold)
    assert ident.noise.accelerometer_noise_density == pytest.approx(
        NoiseModel().accelerometer_noise_density, rel=0.35)
    assert ident.noise.mocap_position_sigma == pytest.approx(
        NoiseModel().mocap_position_sigma, rel=0.25)
