"""The smoothing width the mocap's noise needs: the ladder of widths is tried narrowest first and
stops at the first that passes, which must be the width the whole ladder gives (the narrowest
that passes, else the best ratio)."""

from __future__ import annotations

import numpy as np
import pytest

from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.policy import gap_threshold
from mocap_calib.core.prepare import noise_band as nb
from mocap_calib.sim.flight import SimConfig, simulate_flight


def _whole_ladder(imu_side, mocap_side, tau, dt, gap, lo, order):
    """Every width's noise / signal ratio, then the rule: the narrowest at most NOISE_RATIO,
    else the smallest ratio."""
    chain = nb._NoiseChain.of(tau, dt, gap, order)
    level = chain.level_of(mocap_side)
    widths = nb._widths(lo)
    ratio = np.array([level * chain.after(s, dt) / max(nb._norm_spread(imu_side, s, dt), 1e-300)
                      for s in widths])
    fine = np.flatnonzero(ratio <= nb.NOISE_RATIO)
    k = int(fine[0]) if len(fine) else int(np.argmin(ratio))
    return float(widths[k]), float(ratio[k])


# Lab mocap; radio-relayed poses; noise no width brings to NOISE_RATIO (the best ratio then).
@pytest.mark.parametrize("position_sigma,rotation_sigma", [(1e-4, 1e-3), (4e-3, 0.05),
                                                           (1.0, 3.0)])
def test_the_width_chosen_is_the_whole_ladders(position_sigma: float,
                                               rotation_sigma: float) -> None:
    sim = simulate_flight(SimConfig(seed=4, duration=40.0, noise=NoiseModel(
        mocap_position_sigma=position_sigma, mocap_rotation_sigma=rotation_sigma)))
    u, tau, dt = sim.imu.t, sim.mocap.t, 0.01
    gap_m, gap_i = nb.mocap_gap(tau), gap_threshold(u)
    gyro = nb.imu_on_grid(u, sim.imu.gyro, dt, gap_i)
    accel = nb.imu_on_grid(u, sim.imu.accel, dt, gap_i)
    rates = nb.mocap_rates(tau, sim.mocap.rotation, dt, gap_m)
    positions = nb.mocap_positions(tau, sim.mocap.position, dt, gap_m)
    got = nb.choose_smoothing(gyro, accel, rates, positions, tau, dt, gap_m)
    rate = _whole_ladder(gyro, rates, tau, dt, gap_m, nb.MIN_RATE_S, 1)
    force = _whole_ladder(accel, positions, tau, dt, gap_m, nb.MIN_FORCE_S, 2)
    assert (got.rate_s, got.rate_noise_ratio) == rate
    assert (got.force_s, got.force_noise_ratio) == force
    if position_sigma > 1e-3:  # noisy poses need more than the narrowest width
        assert got.rate_s > nb.MIN_RATE_S and got.force_s > nb.MIN_FORCE_S
        if position_sigma > 0.1:
            assert got.force_noise_ratio > nb.NOISE_RATIO and got.force_s == nb.MAX_SMOOTH_S
    else:
        assert (got.rate_s, got.force_s) == (nb.MIN_RATE_S, nb.MIN_FORCE_S)
