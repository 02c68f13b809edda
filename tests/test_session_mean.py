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


def test_a_segment_refit_reuses_the_solutions_evaluation(fitted, monkeypatch) -> None:
    """A refit of a third of the windows from the solution, under its noise model, takes the
    solution's evaluation for its first step: the same answer as running the filter on those
    windows again (within rounding: the batches differ), and under another noise model no
    reuse."""
    from mocap_calib.core.position.windows import Seed

    pos, model = fitted.pos, fitted.opts.model
    n = pos.takes[0].windows.count
    which = [np.arange(n // 3, 2 * n // 3)]
    hits: list[bool] = []
    reuse = Seed.reuse

    def counted(self, *args):
        out = reuse(self, *args)
        hits.append(out is not None)
        return out

    monkeypatch.setattr(Seed, "reuse", counted)
    seeded = refit(pos, model, which)
    assert hits == [True]
    monkeypatch.setattr(Seed, "reuse", lambda self, *args: None)
    again = refit(pos, model, which)
    np.testing.assert_allclose(seeded.takes[0].knots, again.takes[0].knots, rtol=1e-9,
                               atol=1e-15)
    for a, b in ((seeded.R_MI, again.R_MI), (seeded.p_MI, again.p_MI)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    assert seeded.takes[0].delta == pytest.approx(again.takes[0].delta, abs=1e-12)
    for name in seeded.cov:
        np.testing.assert_allclose(seeded.cov[name], again.cov[name], rtol=1e-8, atol=0.0,
                                   err_msg=name)
    monkeypatch.setattr(Seed, "reuse", counted)
    hits.clear()
    refit(pos, model, which, noise=pos.noise.imu_scaled(3.0))
    assert not any(hits)
