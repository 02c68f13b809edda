"""Both streams on a uniform grid, and how much to low-pass them: as much as the mocap's noise
needs.

Signals that compare the IMU with the mocap (the clock search's, the closed-form fits of the
conventions and motion checks) pass both sides through one low-pass filter, a Gaussian of width
``s``; any linear filter keeps a linear relation (the gyro and the mocap's body rates differ by
the constant ``R_MI``), and it keeps the mocap's differentiation noise out of the band
compared.

The width comes from the data. The mocap side's noise level is read off the top of its band
(above ~20 Hz on a 100 Hz grid, where motion has little power: what a local cubic leaves) as
the level of white pose noise that would leave as much there; that white noise is run through
the same gridding, differencing and filter; ``s`` is the narrowest width at which it is at most
:data:`NOISE_RATIO` of the signal's variation (the IMU side's, which the mocap's noise does
not reach). Lab mocap (0.1 mm, 0.1 deg at 100 Hz and more) keeps the narrow
:data:`MIN_RATE_S` / :data:`MIN_FORCE_S`; poses with degree-level jitter (relayed over a
radio, quantised) get the width that their noise calls for.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d

from mocap_calib.core.model import so3
from mocap_calib.core.policy import gap_threshold

Array = NDArray[np.float64]
Mask = NDArray[np.bool_]

#: Narrowest smoothing (Gaussian sigma, s) of the angular speed and of the specific force.
MIN_RATE_S = 0.02
MIN_FORCE_S = 0.03
#: Widest smoothing tried (s), and the ratio between widths tried.
MAX_SMOOTH_S = 0.5
LADDER = 1.25
#: The mocap's noise after smoothing may be at most this fraction of the signal's variation.
NOISE_RATIO = 0.2
#: Grid points within this many widths of a gap are left out (the filter reaches them).
REACH = 3.0
#: Grid points of the cubic whose residual measures the noise at the top of the band.
HP_WINDOW = 7
#: Mocap holes up to this long (s) are bridged by interpolation, not treated as gaps.
BRIDGE_S = 0.05


@dataclass(frozen=True)
class Smoothing:
    """The widths chosen (Gaussian sigma, s) and the mocap noise / signal ratio at each."""

    rate_s: float
    force_s: float
    rate_noise_ratio: float
    force_noise_ratio: float


@dataclass(frozen=True)
class Gridded:
    """A stream on the grid ``start + k dt``: values (n, 3) and the points in gaps."""

    start: float
    values: Array
    in_gap: Mask


def smooth(x: Array, s: float, dt: float, order: int = 0) -> Array:
    """Gaussian smoothing of width ``s`` (s) along axis 0, or its ``order``-th derivative."""
    return gaussian_filter1d(x, s / dt, axis=0, order=order, mode="reflect") / dt**order


def near_gap(in_gap: Mask, s: float, dt: float) -> Mask:
    """Points a filter of width ``s`` reaches from a gap or an end of the stream (and the
    gap's own points): there it sees interpolated or padded values."""
    edge = in_gap.copy()
    edge[[0, -1]] = True
    return _dilate(edge, int(np.ceil(REACH * s / dt)))


def _dilate(mask: Mask, n: int) -> Mask:
    return np.convolve(mask.astype(float), np.ones(2 * n + 1), mode="same") > 0


def mocap_gap(tau: Array) -> float:
    """Longest mocap hole (s) the signals bridge: the gap rule's, and at least
    :data:`BRIDGE_S` (the filters are about as wide, so interpolating across shorter holes,
    such as a radio link's dropouts, changes nothing they keep)."""
    return max(gap_threshold(tau), BRIDGE_S)


def _gaps_on_grid(t: Array, grid: Array, gap: float) -> Mask:
    idx = np.clip(np.searchsorted(t, grid), 1, len(t) - 1)
    return (t[idx] - t[idx - 1]) > gap


def imu_on_grid(u: Array, x: Array, dt: float, gap: float) -> Gridded:
    """IMU samples averaged over a grid step (no aliasing of fast vibration into the band),
    then sampled on the grid."""
    rate = 1.0 / float(np.median(np.diff(u)))
    n = max(1, int(round(dt * rate))) | 1  # odd: centred (an even box delays by half a sample)
    k = np.ones(n) / n
    box = np.stack([np.convolve(x[:, i], k, mode="same") for i in range(3)], axis=1)
    grid = np.arange(u[0], u[-1], dt)
    vals = np.stack([np.interp(grid, u, box[:, i]) for i in range(3)], axis=1)
    return Gridded(float(grid[0]), vals, _gaps_on_grid(u, grid, gap))


def mocap_rates(tau: Array, R: Array, dt: float, gap: float) -> Gridded:
    """Body rates (rad/s) by central differences of the grid attitudes (interpolated on the
    geodesic between the poses around each grid point), on the grid points."""
    grid = np.arange(tau[0], tau[-1], dt)
    i = np.clip(np.searchsorted(tau, grid, side="right") - 1, 0, len(tau) - 2)
    a = np.clip((grid - tau[i]) / (tau[i + 1] - tau[i]), 0.0, 1.0)
    d = so3.log(np.einsum("nji,njk->nik", R[i], R[i + 1]))
    Rg = R[i] @ so3.exp(a[:, None] * d)
    w = so3.log(np.einsum("nji,njk->nik", Rg[:-2], Rg[2:])) / (2.0 * dt)
    in_gap = _gaps_on_grid(tau, grid, gap)
    return Gridded(float(grid[1]), w, in_gap[2:] | in_gap[1:-1] | in_gap[:-2])


def mocap_positions(tau: Array, p: Array, dt: float, gap: float) -> Gridded:
    grid = np.arange(tau[0], tau[-1], dt)
    vals = np.stack([np.interp(grid, tau, p[:, i]) for i in range(3)], axis=1)
    return Gridded(float(grid[0]), vals, _gaps_on_grid(tau, grid, gap))


def _widths(lo: float) -> Array:
    n = int(np.ceil(np.log(MAX_SMOOTH_S / lo) / np.log(LADDER))) + 1
    return np.minimum(lo * LADDER ** np.arange(n), MAX_SMOOTH_S)


def _high_pass(x: Array) -> Array:
    """What a cubic fitted (least squares) over :data:`HP_WINDOW` grid points leaves at its
    centre: the top of the band (above ~20 Hz on a 100 Hz grid), where motion has little
    power and noise the most. The ends are zero."""
    half = HP_WINDOW // 2
    j = np.arange(-half, half + 1, dtype=float)
    weights = np.linalg.pinv(j[:, None] ** np.arange(4))[0]  # the fit's value at the centre
    out = np.zeros_like(x)
    for k, c in enumerate(weights):
        out[half:len(x) - half] += c * x[k:len(x) - 2 * half + k]
    out[half:len(x) - half] = x[half:len(x) - half] - out[half:len(x) - half]
    return out


def _rms(x: Array, ok: Mask) -> float:
    return float(np.sqrt(np.mean(x[ok] ** 2))) if np.any(ok) else 0.0


@dataclass(frozen=True)
class _NoiseChain:
    """Unit white noise on the poses taken where the mocap side goes: gridded as the poses
    are, differenced as the rates are (``order`` 1), to be smoothed (and twice differentiated for
    the acceleration, ``order`` 2). Seeded: the same poses give the same numbers."""

    values: Array
    in_gap: Mask
    order: int

    @classmethod
    def of(cls, tau: Array, dt: float, gap: float, order: int) -> _NoiseChain:
        rng = np.random.default_rng(0)
        grid = np.arange(tau[0], tau[-1], dt)
        n = np.stack([np.interp(grid, tau, rng.normal(size=len(tau))) for _ in range(3)],
                     axis=1)
        in_gap = _gaps_on_grid(tau, grid, gap)
        if order == 1:  # central differences, as the rates
            n = (n[2:] - n[:-2]) / (2.0 * dt)
            in_gap = in_gap[2:] | in_gap[1:-1] | in_gap[:-2]
        return cls(n, in_gap, order)

    def after(self, s: float, dt: float) -> float:
        """The noise's RMS per axis after smoothing of width ``s``."""
        y = smooth(self.values, s, dt, order=2 if self.order == 2 else 0)
        return _rms(y, ~near_gap(self.in_gap, s, dt))

    def level_of(self, side: Gridded) -> float:
        """The white pose noise (per axis, the stream's unit) that explains the top of the
        band of the mocap side ``side`` (its values gridded as this chain's)."""
        edge = side.in_gap | self.in_gap
        edge[[0, -1]] = True
        ok = ~_dilate(edge, HP_WINDOW // 2)
        unit = _rms(_high_pass(self.values), ok)
        return _rms(_high_pass(side.values), ok) / unit if unit > 0 else 0.0


def _choose(widths: Array, ratio_at: Callable[[float], float]) -> tuple[float, float]:
    """The narrowest width whose noise is at most :data:`NOISE_RATIO` of the signal (else
    the one with the best ratio), and that ratio. ``ratio_at(s)`` is the noise over the signal
    at width ``s``; the widths are tried narrowest first and the search stops at the first
    that passes (lab mocap: the narrowest)."""
    ratios = []
    for s in widths:
        ratios.append(ratio_at(float(s)))
        if ratios[-1] <= NOISE_RATIO:
            break
    k = len(ratios) - 1 if ratios[-1] <= NOISE_RATIO else int(np.argmin(ratios))
    return float(widths[k]), float(ratios[k])


def _norm_spread(side: Gridded, s: float, dt: float) -> float:
    norm = np.linalg.norm(smooth(side.values, s, dt), axis=1)
    ok = ~near_gap(side.in_gap, s, dt)
    return float(np.std(norm[ok])) if np.sum(ok) > 1 else 0.0


def choose_smoothing(gyro: Gridded, accel: Gridded, rates: Gridded, positions: Gridded,
                     tau: Array, dt: float, gap: float) -> Smoothing:
    """The widths for the angular speed and the specific force (see the module's text):
    the mocap side's noise level is read off the top of its band, run through the filter of
    each width and compared with the IMU side's variation at that width."""
    out = []
    for imu_side, mocap_side, lo, order in ((gyro, rates, MIN_RATE_S, 1),
                                            (accel, positions, MIN_FORCE_S, 2)):
        chain = _NoiseChain.of(tau, dt, gap, order)
        level = chain.level_of(mocap_side)

        def ratio_at(s: float, chain: _NoiseChain = chain, level: float = level,
                     imu_side: Gridded = imu_side) -> float:
            noise = level * chain.after(s, dt)
            return noise / max(_norm_spread(imu_side, s, dt), 1e-300)

        out.append(_choose(_widths(lo), ratio_at))
    (rs, rr), (fs, fr) = out
    return Smoothing(rs, fs, rr, fr)


def noise_band(u: Array, gyro: Array, accel: Array, tau: Array, R: Array, p: Array,
               dt: float = 0.01) -> Smoothing:
    """The widths two raw streams need (see :func:`choose_smoothing`), both on a grid of
    step ``dt``."""
    gap_m = mocap_gap(tau)
    gap_i = gap_threshold(u)
    return choose_smoothing(imu_on_grid(u, gyro, dt, gap_i), imu_on_grid(u, accel, dt, gap_i),
                            mocap_rates(tau, R, dt, gap_m), mocap_positions(tau, p, dt, gap_m),
                            tau, dt, gap_m)
