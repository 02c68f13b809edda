"""The session-mean bias's two covariances: against the bias's mean over time (what a reported
sigma is) and as the knots' mean's own (what comparing two fits of one session uses)."""

from __future__ import annotations

import numpy as np
import pytest

from mocap_calib.core.model.parameters import ACCEL_BIAS, GYRO_BIAS
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import Recording, fit_takes
from mocap_calib.core.uncertainty.refit import everything, refit
from mocap_calib.sim.flight import SimConfig, simulate_flight

pytestmark = pytest.mark.slow  # a calibration and two refits


@pytest.fixture(scope="module")
def fitted():
    sim = simulate_flight(SimConfig(seed=5, duration=40.0, effects={"time_offset": None}))
    return fit_takes([Recording(sim.imu, sim.mocap)], CalibrationOptions(noise_from_data=False))


def test_only_the_biases_covariance_depends_on_which_mean(fitted) -> None:
    """A refit with either kind gives the same estimates and the same covariances of every
    block but the biases; the knots' mean's own covariance is the same in both; the biases'
    against the time mean differ from it (the walk inside the windows and the data on it)."""
    pos = fitted.pos
    model = fitted.opts.model
    kinds = {k: refit(pos, model, everything(pos), time_mean=k) for k in (False, True)}
    a, b = kinds[False], kinds[True]
    np.testing.assert_array_equal(a.takes[0].knots, b.takes[0].knots)
    np.testing.assert_array_equal(a.accel_bias_mean, b.accel_bias_mean)
    biases = (GYRO_BIAS.name, ACCEL_BIAS.name)
    assert set(a.cov) == set(b.cov)
    for name in a.cov:
        if name not in biases:
            np.testing.assert_array_equal(a.cov[name], b.cov[name], err_msg=name)
    for name in biases:
        np.testing.assert_array_equal(a.takes[0].cov_knots[name], b.takes[0].cov_knots[name])
        np.testing.assert_array_equal(a.cov[name], a.takes[0].cov_knots[name])
        assert not np.allclose(b.cov[name], b.takes[0].cov_knots[name], rtol=1e-3, atol=0.0)
    # The comparison covariance holds the biases only: the other blocks' (sandwich-raised)
    # covariances are never shadowed by it.
    assert set(a.takes[0].cov_knots) == set(b.takes[0].cov_knots) == set(biases)
