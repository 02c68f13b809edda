"""The distribution functions and signal filters the calibration uses without importing
scipy.stats / scipy.signal (together ~45 MB resident and ~0.3 s at every start): the same
numbers as scipy's own, on grids that include the far tails and the signal's ends."""

from __future__ import annotations

import numpy as np
import pytest
from loaded import loaded_by
from scipy import signal, stats

from mocap_calib.core.model import stats as light


@pytest.mark.parametrize("k", [1, 2, 3, 6, 9, 18])
def test_chi2_and_f_match_scipy_stats(k: int) -> None:
    for x in [0.0, 1e-3, 0.5, 3.0, 40.0, 400.0, 3000.0]:
        assert light.chi2_sf(x, k) == stats.chi2.sf(x, k)
        assert light.chi2_logsf(x, k) == pytest.approx(stats.chi2.logsf(x, k), rel=1e-12)
        assert light.f_logsf(x, k, 40 - k) == pytest.approx(stats.f.logsf(x, k, 40 - k), rel=1e-12)
    for p in [1e-300, 1e-12, 0.001, 0.5, 0.999]:
        assert light.chi2_isf(p, k) == pytest.approx(stats.chi2.isf(p, k), rel=1e-14)
        assert light.chi2_ppf(p, k) == pytest.approx(stats.chi2.ppf(p, k), rel=1e-14)
    assert light.chi2_median(k) == pytest.approx(stats.chi2.median(k), rel=1e-14)
    for z in [-3.0, 0.0, 5.0, 40.0]:
        assert light.norm_logsf(z) == pytest.approx(stats.norm.logsf(z), rel=1e-14)


def test_the_calibration_imports_neither_scipy_stats_nor_signal() -> None:
    code = "import mocap_calib.workflows.calibrate, mocap_calib.core.pipeline.calibrate"
    assert loaded_by(code, ["scipy.stats", "scipy.signal"]) == []


def test_clock_filters_match_scipy_signal() -> None:
    from mocap_calib.core.clock import filters

    rng = np.random.default_rng(4)
    a, b = rng.normal(size=700), rng.normal(size=1100)
    ref = signal.correlate(a, b, mode="full", method="fft")
    np.testing.assert_allclose(filters.correlate_full(a, b), ref, atol=1e-10)
    z = np.round(np.cumsum(rng.normal(size=5000)), 1)  # plateaus and ties
    z[100:130] = -1e9
    for d in (1, 2, 10, 100):
        np.testing.assert_array_equal(filters.peaks_apart(z, d),
                                      signal.find_peaks(z, distance=d)[0])
