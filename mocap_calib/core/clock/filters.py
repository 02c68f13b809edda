"""The few signal operations the coarse clock search needs, written out: importing
scipy.signal (which imports scipy.stats) costs ~45 MB resident and ~0.3 s at every start. Each
does what the scipy.signal function of the same purpose does (``tests/test_light_scipy.py``
compares them): the full cross-correlation by FFT, and the local maxima kept at least a
distance apart."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft
from numpy.typing import NDArray

Array = NDArray[np.float64]


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
