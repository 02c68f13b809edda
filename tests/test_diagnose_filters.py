"""The diagnosis' filters give scipy.signal's numbers (low-pass design and zero-phase
filtering, Welch spectra, the AR(1) recursion) without importing it."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy import signal

from mocap_calib.core.diagnosis.filters import ar1, butter_lowpass, sosfiltfilt, welch


@pytest.mark.parametrize("cutoff,rate", [(2.0, 200.0), (10.0, 100.0), (2.0, 506.0),
                                         (40.0, 100.0)])
def test_low_pass_matches_scipy(cutoff: float, rate: float) -> None:
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(size=(700, 3)), axis=0) + rng.normal(size=(700, 3))
    ours = butter_lowpass(4, cutoff, rate)
    ref = signal.butter(4, cutoff, fs=rate, output="sos")
    w = np.linspace(0.0, np.pi, 50)
    np.testing.assert_allclose(np.abs(signal.sosfreqz(ours, w)[1]),
                               np.abs(signal.sosfreqz(ref, w)[1]), atol=1e-12)
    got = sosfiltfilt(ours, x)
    want = signal.sosfiltfilt(ref, x, axis=0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())
    np.testing.assert_allclose(sosfiltfilt(ours, x[:, 0]), want[:, 0], rtol=0,
                               atol=1e-9 * np.abs(want).max())
    with pytest.raises(ValueError):
        sosfiltfilt(ours, x[:15])


@pytest.mark.parametrize("n,nper", [(1000, 128), (1001, 64), (4096, 1024), (777, 65)])
def test_welch_matches_scipy(n: int, nper: int) -> None:
    x = np.random.default_rng(4).normal(size=(n, 3)) + np.arange(n)[:, None] * 1e-3
    f, p = welch(x, 200.0, nper)
    f_ref, p_ref = signal.welch(x, fs=200.0, nperseg=nper, axis=0)
    np.testing.assert_allclose(f, f_ref)
    np.testing.assert_allclose(p, p_ref, rtol=1e-10, atol=1e-14)


def test_ar1_matches_lfilter() -> None:
    e = np.random.default_rng(5).normal(size=(500, 3))
    a = 0.93
    np.testing.assert_allclose(ar1(e, a, np.sqrt(1 - a * a)),
                               signal.lfilter([np.sqrt(1 - a * a)], [1.0, -a], e, axis=0),
                               rtol=1e-12, atol=1e-14)


def test_a_diagnosis_imports_neither_scipy_signal_nor_stats() -> None:
    code = ("import sys; import mocap_calib.core.diagnosis.diagnose, "
            "mocap_calib.core.diagnosis.auto; "
            "print([m for m in ('scipy.signal', 'scipy.stats') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"
