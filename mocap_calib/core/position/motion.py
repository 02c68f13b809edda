"""The motion's own signals: what the Jacobians of the effects that move samples in time are
built from.

The clock offset (and the IMU clock's rate, the accelerometer's lag) moves the motion the IMU
measured along the time axis, not the sensor's noise: white noise and rotor vibration aliased
by the sampling belong to each sample and do not move with the clock. The exact derivative of
a window's residuals with respect to a time shift is the rate of change of the samples, noise
included, read at the mocap's sample instants; there, content above the mocap's Nyquist
frequency folds back into the motion's band (a rotor line the 200 Hz IMU aliases to 95 Hz is a
5 Hz line in 100 Hz mocap steps). Counted as information about the shift, that noise made the
clock offset's sigma a third too small on simulated flights with rotor vibration (the ``flying``
preset: 0.068 ms for errors of 0.097 ms RMS over 24 flights), and the estimate no better.

So the timing columns are built from the IMU samples smoothed by a Gaussian kernel whose
response at the Nyquist frequency of the windows' samples (the lower of the IMU's and the
mocap's) is :data:`ALIAS_GAIN`: an estimate of the motion's signal that does not carry the
samples' noise. The residuals stay the raw samples' (the noise model accounts for their
noise), so the solution solves the instrumental-variable equations ``Z^T W r = 0`` with those
columns as ``Z``; the covariance (model and sandwich) is theirs.
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

#: The smoother's response at the Nyquist frequency of the windows' samples (-40 dB).
ALIAS_GAIN = 0.01
#: The kernel is cut at this many standard deviations.
KERNEL_SIGMAS = 4.0
#: Sessions whose smoothed signals are kept (every refit of a session reads the same ones).
CACHED_SESSIONS = 4

_cache: OrderedDict[tuple[int, int, int, float], tuple[list[weakref.ref], tuple[Array, Array]]]
_cache = OrderedDict()
_cache_lock = threading.Lock()


def kernel_sigma(nyquist_hz: float) -> float:
    """Standard deviation (s) of the Gaussian kernel whose response at ``nyquist_hz`` is
    :data:`ALIAS_GAIN` (the response at ``f`` is ``exp(-(2 pi f sigma)^2 / 2)``)."""
    return float(np.sqrt(2.0 * np.log(1.0 / ALIAS_GAIN)) / (2.0 * np.pi * nyquist_hz))


def motion_signals(u: Array, gyro: Array, accel: Array, nyquist_hz: float) -> tuple[Array, Array]:
    """Gyro and accelerometer samples smoothed by the Gaussian kernel of
    :func:`kernel_sigma` in time (weights from the samples' own stamps, normalised: a gap or
    the stream's end leaves a one-sided average, nothing is extrapolated).

    Computed once per session: the answer is kept for the same sample arrays (the same
    objects, held by weak reference) and band, which every refit of a session passes."""
    arrays = (u, gyro, accel)
    key = (id(u), id(gyro), id(accel), float(nyquist_hz))
    with _cache_lock:
        hit = _cache.get(key)
        if hit is not None and all(r() is a for r, a in zip(hit[0], arrays, strict=True)):
            _cache.move_to_end(key)
            return hit[1]
    out = _smooth(u, gyro, accel, nyquist_hz)
    for a in out:
        a.flags.writeable = False  # shared by every caller
    try:
        refs = [weakref.ref(a) for a in arrays]
    except TypeError:  # not weakly referenceable (not an ndarray): nothing kept
        return out
    with _cache_lock:
        _cache[key] = (refs, out)
        while len(_cache) > CACHED_SESSIONS:
            _cache.popitem(last=False)
    return out


def _smooth(u: Array, gyro: Array, accel: Array, nyquist_hz: float) -> tuple[Array, Array]:
    u = np.asarray(u, dtype=float)
    y = np.concatenate([gyro, accel], axis=1)
    n = len(u)
    sigma = kernel_sigma(nyquist_hz)
    step = float(np.median(np.diff(u))) if n > 1 else 0.0
    k = int(np.ceil(KERNEL_SIGMAS * sigma / step)) if step > 0 else 0
    num, den = y.copy(), np.ones(n)
    for j in range(1, min(k, n - 1) + 1):
        w = np.exp(-0.5 * ((u[j:] - u[:-j]) / sigma) ** 2)
        num[j:] += w[:, None] * y[:-j]
        num[:-j] += w[:, None] * y[j:]
        den[j:] += w
        den[:-j] += w
    out = num / den[:, None]
    return np.ascontiguousarray(out[:, :3]), np.ascontiguousarray(out[:, 3:])
