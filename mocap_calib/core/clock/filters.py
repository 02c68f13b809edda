"""The few signal filters the coarse clock search needs, written out: importing scipy.signal
(which imports scipy.stats) costs ~45 MB resident and ~0.3 s at every start. Each does what
the scipy.signal function of the same purpose does (``tests/test_light_scipy.py`` compares
them): a 5-sample median, Savitzky-Golay smoothing and derivatives with polynomial ends, the
full cross-correlation by FFT, and the local maxima kept at least a distance apart."""

from __future__ import annotations

from dataclasses import dataclass
from math import factorial

import numpy as np
import scipy.fft
from numpy.lib.stride_tricks import sliding_window_view
from numpy.typing import NDArray

Array = NDArray[np.float64]


def median5(y: Array) -> Array:
    """Running median of 5 samples, the ends padded with zeros."""
    padded = np.concatenate([np.zeros(2), np.asarray(y, dtype=float), np.zeros(2)])
    return np.median(sliding_window_view(padded, 5), axis=1)


def savgol(x: Array, window: int, order: int, deriv: int = 0, delta: float = 1.0) -> Array:
    """Savitzky-Golay filter along axis 0: at every sample the ``deriv``-th derivative of the
    degree-``order`` polynomial fitted (least squares) to the ``window`` (odd) samples centred
    on it; the first and last ``window // 2`` samples take the polynomial fitted to the first
    and last ``window`` samples. ``delta``: the sample spacing."""
    x = np.asarray(x, dtype=float)
    flat = x.reshape(len(x), -1)
    half = window // 2
    scale = factorial(deriv) / delta**deriv
    j = np.arange(-half, half + 1, dtype=float)
    # Row `deriv` of the fit's pseudo-inverse: the weights of the centre derivative.
    weights = np.linalg.pinv(j[:, None] ** np.arange(order + 1))[deriv] * scale
    out = np.empty_like(flat)
    out[half:len(flat) - half] = sliding_window_view(flat, window, axis=0) @ weights
    # The ends: the polynomial fitted to the first / last `window` samples, its `deriv`-th
    # derivative (d^deriv/dk^deriv of sum c_i k^i) at the samples the centred fit cannot reach.
    k = np.arange(window, dtype=float)
    powers = np.arange(order + 1)
    V = k[:, None] ** powers
    fall = np.array([np.prod(np.arange(i - deriv + 1, i + 1)) if i >= deriv else 0.0
                     for i in powers])
    n = len(flat)
    for fit, at, dest in ((slice(0, window), k[:half], slice(0, half)),
                          (slice(n - window, n), k[window - half:], slice(n - half, n))):
        coef = np.linalg.lstsq(V, flat[fit], rcond=None)[0]  # (order+1, d)
        D = np.where(powers >= deriv, fall * at[:, None] ** np.maximum(powers - deriv, 0), 0.0)
        out[dest] = D @ coef / delta**deriv
    return out.reshape(x.shape)


def correlate_full(a: Array, b: Array) -> Array:
    """``c[k] = sum_n a[n + k - (len(b) - 1)] b[n]`` for every overlap (by FFT)."""
    sp = Spectra(len(a), len(b))
    return sp.correlate(sp.of_a(a), sp.of_b(b))


@dataclass(frozen=True)
class Spectra:
    """:func:`correlate_full` of signals of lengths ``n_a`` and ``n_b`` from their transforms,
    so that a signal correlated with several others is transformed once."""

    n_a: int
    n_b: int

    @property
    def n(self) -> int:
        return scipy.fft.next_fast_len(self.n_a + self.n_b - 1, real=True)

    def of_a(self, a: Array) -> Array:
        return scipy.fft.rfft(a, self.n)

    def of_b(self, b: Array) -> Array:
        return scipy.fft.rfft(b[::-1], self.n)

    def correlate(self, fa: Array, fb: Array) -> Array:
        return scipy.fft.irfft(fa * fb, self.n)[:self.n_a + self.n_b - 1]


def peaks_apart(x: Array, distance: int) -> NDArray[np.int64]:
    """Indices of the local maxima of ``x`` (a flat top: its middle sample, rounded down; the
    ends are never maxima), the highest first keeping those at least ``distance`` apart, in
    index order."""
    peaks = []
    i, last = 1, len(x) - 1
    while i < last:
        if x[i - 1] < x[i]:
            ahead = i + 1
            while ahead < last and x[ahead] == x[i]:
                ahead += 1
            if x[ahead] < x[i]:
                peaks.append((i + ahead - 1) // 2)
                i = ahead
        i += 1
    idx = np.asarray(peaks, dtype=np.int64)
    if distance <= 1 or len(idx) < 2:
        return idx
    keep = np.ones(len(idx), dtype=bool)
    for j in np.argsort(x[idx])[::-1]:  # highest first
        if not keep[j]:
            continue
        k = j - 1
        while k >= 0 and idx[j] - idx[k] < distance:
            keep[k] = False
            k -= 1
        k = j + 1
        while k < len(idx) and idx[k] - idx[j] < distance:
            keep[k] = False
            k += 1
    return idx[keep]
