"""Honest sigmas, tested both ways: errors against the simulator's truth divided by the reported
sigmas must scatter like a unit normal (a padded sigma fails as surely as an optimistic one).

Two simulators, as in scripts/sigma_study.py (whose 30-seed figures are in the README): clean
(white mocap noise) and realistic (mocap noise correlated over 0.1-0.5 s). Pooled over a few
seeds and every parameter component, the standard deviation must lie in [0.6, 1.4] (a sample of
about 80 values has a standard error of about 0.08 on it) and no |z| may exceed 4.5.
"""

from __future__ import annotations

import numpy as np
import pytest
from simtruth import z_scores

from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.sim.flight import SimConfig, simulate_flight

SEEDS = range(500, 506)


@pytest.mark.parametrize("corr", [0.0, "drawn"], ids=["clean", "realistic"])
def test_error_over_sigma_is_unit_normal_both_ways(corr: object) -> None:
    z_all = []
    for seed in SEEDS:
        tau = float(np.random.default_rng([seed, 77]).uniform(0.1, 0.5)) if corr else 0.0
        sim = simulate_flight(SimConfig(seed=seed, duration=60.0,
                                        effects={"time_offset": None}, mocap_noise_corr=tau))
        res = calibrate(sim.imu, sim.mocap, CalibrationOptions())
        z_all.append(np.concatenate(list(z_scores(res, sim.truth).values())))
    z = np.concatenate(z_all)
    assert 0.6 <= np.std(z) <= 1.4, f"std of error/sigma {np.std(z):.2f} over {z.size} values"
    assert np.max(np.abs(z)) <= 4.5, f"max |error|/sigma {np.max(np.abs(z)):.2f}"
