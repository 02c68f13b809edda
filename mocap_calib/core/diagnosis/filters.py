"""The filters of the measurement-domain comparison: the zero-phase Butterworth low-pass, Welch
spectra and the AR(1) recursion of the simulated mocap noise, in numpy and one compiled kernel.
They give scipy.signal's numbers (``tests/test_diagnose_filters.py``) without importing it:
scipy.signal, and the scipy.stats it imports, cost a diagnosis 0.6 s of CPU at start.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.jit import kernel

Array = NDArray[np.float64]


def butter_lowpass(order: int, cutoff: float, rate: float) -> Array:
    """Second-order sections (rows ``b0 b1 b2 1 a1 a2``) of the digital Butterworth low-pass
    of ``order`` (even) and ``cutoff`` Hz at ``rate`` Hz: the analog prototype's poles at the
    pre-warped cutoff, mapped by the bilinear transform; zeros at z = -1; unit gain at DC."""
    warped = 4.0 * np.tan(np.pi * cutoff / rate)  # pre-warped, the transform's fs = 2
    p = -np.exp(1j * np.pi * np.arange(-order + 1, order, 2) / (2 * order)) * warped
    pz = (4.0 + p) / (4.0 - p)
    # One section per conjugate pair (upper half plane), the pair nearest the unit circle last.
    upper = sorted((z for z in pz if z.imag > 0), key=lambda z: 1.0 - abs(z), reverse=True)
    sos = np.zeros((len(upper), 6))
    for i, z in enumerate(upper):
        a = np.array([1.0, -2.0 * z.real, abs(z) ** 2])
        sos[i] = [*(np.array([1.0, 2.0, 1.0]) * a.sum() / 4.0), *a]
    return sos


def sosfiltfilt(sos: Array, x: Array) -> Array:
    """Forward-backward filtering of ``x`` (n, k) along its first axis by ``sos``, with odd
    extension of ``3 (2 sections + 1)`` samples at each end and the steady-state start of a
    step at each pass's first sample (scipy.signal.sosfiltfilt's defaults)."""
    x = np.asarray(x, dtype=float)
    flat = x.ndim == 1
    x2 = x[:, None] if flat else x
    pad = 3 * (2 * len(sos) + 1)
    if len(x2) <= pad:
        raise ValueError(f"{len(x2)} samples: the filter needs more than {pad}")
    ext = np.concatenate([2.0 * x2[0] - x2[pad:0:-1], x2,
                          2.0 * x2[-1] - x2[-2:-pad - 2:-1]])
    zi = _steady_state(sos)
    y = _sosfilt(sos, ext, zi[:, :, None] * ext[0][None, None, :])
    y = _sosfilt(sos, y[::-1].copy(), zi[:, :, None] * y[-1][None, None, :])[::-1]
    out = y[pad:-pad]
    return out[:, 0] if flat else out


def _steady_state(sos: Array) -> Array:
    """Each section's state (2,) for a unit step in steady state (times the gain of the
    sections before it)."""
    zi = np.zeros((len(sos), 2))
    scale = 1.0
    for i, (b, a) in enumerate(zip(sos[:, :3], sos[:, 3:], strict=True)):
        companion_t = np.array([[-a[1], 1.0], [-a[2], 0.0]])
        zi[i] = scale * np.linalg.solve(np.eye(2) - companion_t, b[1:] - a[1:] * b[0])
        scale *= b.sum() / a.sum()
    return zi


@kernel
def _sosfilt(sos: Array, x: Array, zi: Array) -> Array:  # pragma: no cover - compiled
    """Direct form II transposed, section after section, every column of ``x`` (n, k)."""
    n, k = x.shape
    y = x.copy()
    for s in range(sos.shape[0]):
        b0, b1, b2 = sos[s, 0], sos[s, 1], sos[s, 2]
        a1, a2 = sos[s, 4], sos[s, 5]
        for j in range(k):
            z0, z1 = zi[s, 0, j], zi[s, 1, j]
            for i in range(n):
                xi = y[i, j]
                yi = b0 * xi + z0
                z0 = b1 * xi - a1 * yi + z1
                z1 = b2 * xi - a2 * yi
                y[i, j] = yi
    return y


def welch(x: Array, rate: float, nperseg: int) -> tuple[Array, Array]:
    """One-sided power spectral density of ``x`` (n, k) by Welch's method: periodic Hann
    segments of ``nperseg`` overlapping by half, each less its mean, averaged (density
    scaling). Returns the frequencies (F,) and the PSD (F, k)."""
    step = nperseg - nperseg // 2
    count = (len(x) - nperseg // 2) // step
    win = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(nperseg) / nperseg)
    starts = np.arange(count) * step
    segs = x[starts[:, None] + np.arange(nperseg)[None, :]]  # (S, nperseg, k)
    segs = segs - segs.mean(axis=1, keepdims=True)
    spec = np.abs(np.fft.rfft(segs * win[None, :, None], axis=1)) ** 2
    spec /= rate * float(np.sum(win ** 2))
    spec[:, 1:-1 if nperseg % 2 == 0 else None] *= 2.0
    return np.fft.rfftfreq(nperseg, 1.0 / rate), spec.mean(axis=0)


@kernel
def ar1(e: Array, a: float, b0: float) -> Array:  # pragma: no cover - compiled
    """``y[i] = b0 e[i] + a y[i - 1]`` along the first axis of ``e`` (n, k), from rest."""
    y = np.empty_like(e)
    n, k = e.shape
    for j in range(k):
        prev = 0.0
        for i in range(n):
            prev = b0 * e[i, j] + a * prev
            y[i, j] = prev
    return y


def run_kernels() -> None:
    """Each kernel once, on the argument types a diagnosis passes them (C-ordered float64
    arrays, float coefficients): the install step (``mocap-calib compile``) runs this so that
    a diagnosis compiles nothing."""
    sosfiltfilt(butter_lowpass(4, 2.0, 100.0), np.zeros((40, 3)))
    ar1(np.zeros((4, 3)), 0.5, 0.5)
