"""Honest sigmas, tested both ways: errors against the simulator's truth divided by the reported
sigmas must scatter like a unit normal (a padded sigma fails as surely as an optimistic one).

Two simulators, as in scripts/sigma_study.py (whose 30-seed figures are in the README): clean
(white mocap noise) and realistic (mocap noise correlated over 0.1-0.5 s). Pooled over a few
seeds and every parameter component (90 values), the RMS of z = error/sigma must lie in
[0.7, 1.3] and its mean within +-0.3 (a standard error is about 0.1; a common bias of one sigma
moves the mean to 1 and the RMS to 1.3, which the standard deviation alone would not see), and
no |z| may exceed 4. Measured (seeds 500-505): RMS 0.87 and 0.87, mean 0.02 and 0.03, largest
|z| 2.1 and 3.0 (clean, realistic).
"""

from __future__ import annotations

import numpy as np
import pytest
from simtruth import z_scores

from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.sim.flight import SimConfig, simulate_flight

SEEDS = range(500, 506)


@pytest.mark.slow
@pytest.mark.parametrize("corr", [0.0, "drawn"], ids=["clean", "realistic"])
def test_error_over_sigma_is_unit_normal_both_ways(corr: object) -> None:
    z_all = []
    for seed in SEEDS:
        tau = float(np.random.default_rng([seed, 77]).uniform(0.1, 0.5)) if corr else 0.0
        sim = simulate_flight(SimConfig(seed=seed, duration=60.0,
                                        effects={"time_offset": None}, mocap_noise_corr=tau))
        res = calibrate(sim.imu, sim.mocap, CalibrationOptions())
        z_all.append(np.concatenate(list(z_scores(res, sim.truth).values())))
    check_unit_normal(np.concatenate(z_all))


def check_unit_normal(z: np.ndarray) -> None:
    """RMS and mean of the normalized errors, and the largest one (see the module's text)."""
    rms, mean = float(np.sqrt(np.mean(z**2))), float(np.mean(z))
    assert 0.7 <= rms <= 1.3, f"RMS of error/sigma {rms:.2f} over {z.size} values"
    assert abs(mean) <= 0.3, f"mean of error/sigma {mean:.2f} over {z.size} values"
    assert np.max(np.abs(z)) <= 4.0, f"max |error|/sigma {np.max(np.abs(z)):.2f}"


@pytest.mark.parametrize("broken", ["bias", "padded", "optimistic", "outlier"])
def test_the_check_fails_on_dishonest_sigmas(broken: str) -> None:
    """Unit-normal z pass; each way of getting sigmas wrong fails: a common 1-sigma bias (which
    the standard deviation misses), sigmas twice too large or too small, one 5-sigma error."""
    z = np.random.default_rng(3).standard_normal(90)
    check_unit_normal(z)
    bad = {"bias": z + 1.0, "padded": z / 2.0, "optimistic": z * 2.0,
           "outlier": np.r_[z[:-1], 5.0]}[broken]
    assert 0.7 <= np.std(bad) <= 1.3 or broken != "bias"  # the old check passed a bias
    with pytest.raises(AssertionError):
        check_unit_normal(bad)
