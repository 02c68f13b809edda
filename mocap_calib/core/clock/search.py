"""Coarse clock alignment that knows when it does not know.

Signals that do not depend on the unknown IMU-to-marker rotation are cross-correlated over
every lag the two recordings allow (so offsets of any size work, also clocks of different
epochs), both sides low-passed alike, as much as the mocap's noise needs
(:mod:`~mocap_calib.core.clock.signals`):

- angular speed: ``|gyro|`` against the mocap's ``|w|`` from its attitudes;
- specific force: ``|accel|`` against ``|a_W - g_W|`` from the mocap's second derivative of
  position; the world's up axis is not known yet, so each axis-aligned up (z-up Vicon, y-up
  OptiTrack, ...) is tried and the best kept. This is the signal of translation-dominated
  sessions, where the body barely rotates.

Each signal's correlation at every lag is turned into the statistic of a test against "no
relation": Fisher's ``atanh(r)`` times ``sqrt(n_eff - 3)``, with ``n_eff`` the overlap's length
over the signals' correlation time (smooth motion, and the smoothing, leave few independent
samples). Without a relation it is about standard normal, so it reads in null sigmas. The
signals' statistics are combined (Stouffer). A lag is resolved when its peak stands out of the
null and clears every other peak (more than a second away) by a margin (null sigmas, and a
fraction of its height); periodic motion gives several peaks of about the same height and is
not resolved. When the raw stamps already share an epoch, lags near zero are searched first.
The chosen peak is refined on the signals at a tenth of a grid step; the pipeline then
confirms the choice by the fine fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core import interrupt
from mocap_calib.core.clock.filters import Spectra, correlate_full, peaks_apart
from mocap_calib.core.clock.signals import ClockSignal, signals
from mocap_calib.core.policy import GRAVITY
from mocap_calib.core.prepare.noise_band import Smoothing
from mocap_calib.core.threads import map_blocks
from mocap_calib.errors import ObservabilityError

Array = NDArray[np.float64]

#: Grid rate (Hz) of the correlation; the result is refined to a fraction of a step.
GRID_HZ = 100.0
#: A peak must stand this many null sigmas above the null's median ...
MIN_PEAK_Z = 6.0
#: ... and this many above every other peak further than :data:`PEAK_SEPARATION_S` away.
MIN_MARGIN_Z = 3.0
PEAK_SEPARATION_S = 1.0
#: ... and by this fraction of its own height: periodic motion gives peaks of nearly equal
#: correlation, and near 1 the Fisher statistic turns small differences in it (the model's,
#: not chance's) into many null sigmas.
MIN_LEAD = 0.1
#: With raw stamps of one epoch, lags within this range (s) are searched first.
SAME_EPOCH_RANGE_S = 5.0


@dataclass(frozen=True)
class ClockSearch:
    """What the coarse search found.

    Attributes:
        time_offset: ``t_d`` (s) relative to the raw stamps: an IMU sample stamped ``t``
            (absolute) was taken at mocap absolute time ``t + t_d``.
        signals: the signals used, with the up axis for specific force.
        peak_z: the chosen peak's height in null sigmas.
        margin_z: its lead over the best other peak (null sigmas).
        second_offset: ``t_d`` of that other peak (None if there is none).
        restricted: only lags near zero were searched (raw stamps of one epoch).
        lags: (n,) ``t_d`` values of the curve (decimated, for reports).
        score: (n,) the combined z-score there.
        candidates: (t_d, z) of the highest local peaks, best first.
    """

    time_offset: float
    signals: tuple[str, ...]
    peak_z: float
    margin_z: float
    second_offset: float | None
    restricted: bool
    lags: Array = field(repr=False, default_factory=lambda: np.zeros(0))
    score: Array = field(repr=False, default_factory=lambda: np.zeros(0))
    candidates: tuple[tuple[float, float], ...] = ()
    verified_by_fit: bool = False  # chosen among equal peaks by stage 1-2 fits
    smoothing: Smoothing | None = None  # the signals' low-pass widths

    @property
    def resolved(self) -> bool:
        return self.peak_z >= MIN_PEAK_Z and self.margin_z >= self.required_margin

    @property
    def required_margin(self) -> float:
        """The lead (null sigmas) the peak needs over every other (see :data:`MIN_LEAD`)."""
        return max(MIN_MARGIN_Z, MIN_LEAD * self.peak_z)

    def to_dict(self) -> dict[str, object]:
        return {"method": "rotation-invariant cross-correlation (Fisher statistic, combined)",
                "signals": list(self.signals), "coarse_time_offset": self.time_offset,
                "peak_z": round(self.peak_z, 2), "margin_z": round(self.margin_z, 2),
                "second_best_time_offset": self.second_offset,
                "searched_near_zero_first": self.restricted,
                "chosen_by_fit_among_peaks": self.verified_by_fit,
                "candidates": [{"time_offset": t, "z": round(z, 2)} for t, z in self.candidates],
                **({} if self.smoothing is None else {"smoothing_s": {
                    "angular speed": self.smoothing.rate_s,
                    "specific force": self.smoothing.force_s}})}


def _correlation(x: Array, y: Array, dt: float,
                 x_spectra: dict[tuple[int, int, int], tuple[Array, ...]] | None = None
                 ) -> tuple[Array, Array, Array]:
    """Pearson correlation of ``y(j)`` and ``x(j - lag)`` over their overlap, for all lags (in
    grid steps), and the overlap's sample count. Centred within each overlap: an uncentred one
    calls two rest periods (both constant) perfectly correlated. Lags with too little overlap,
    or an overlap in which either signal barely varies, are NaN. ``x_spectra``: a cache of
    ``x``'s transforms by its id (the specific force's IMU side is one array for every up
    axis; the caller keeps the arrays alive, so the ids are theirs)."""
    sp = Spectra(len(y), len(x))
    cache = {} if x_spectra is None else x_spectra
    key = (id(x), sp.n_a, sp.n_b)
    if key not in cache:
        cache[key] = tuple(sp.of_b(b) for b in (np.ones_like(x), x, x * x))
    f_ones_x, f_x, f_xx = cache[key]
    f_ones_y, f_y, f_yy = (sp.of_a(a) for a in (np.ones_like(y), y, y * y))
    n = np.maximum(np.rint(sp.correlate(f_ones_y, f_ones_x)), 1.0)
    sx, sy = sp.correlate(f_ones_y, f_x), sp.correlate(f_y, f_ones_x)
    cov = sp.correlate(f_y, f_x) - sx * sy / n
    vx = sp.correlate(f_ones_y, f_xx) - sx * sx / n
    vy = sp.correlate(f_yy, f_ones_x) - sy * sy / n
    min_overlap = max(int(5.0 / dt), int(0.2 * min(len(x), len(y))))
    valid = (n > min_overlap) & (vx > 0.05 * np.var(x) * n) & (vy > 0.05 * np.var(y) * n)
    corr = np.where(valid, cov / np.sqrt(np.maximum(vx * vy, 1e-300)), np.nan)
    return corr, n, np.arange(-(len(x) - 1), len(y))


def _correlation_time(z: Array, dt: float) -> float:
    """Integral time scale (s) of a mean-removed signal: its autocorrelation summed up to the
    first zero crossing (the span over which samples are not independent)."""
    ac = correlate_full(z, z)[len(z) - 1:]
    ac = ac / max(ac[0], 1e-300)
    first_neg = np.flatnonzero(ac <= 0.0)
    stop = int(first_neg[0]) if len(first_neg) else len(ac)
    return max(dt, float(np.sum(ac[:stop])) * dt)


def _statistic(corr: Array, n: Array, tau_c: float, dt: float) -> Array:
    """Fisher's ``atanh(r) sqrt(n_eff - 3)``: about N(0, 1) at lags where nothing relates."""
    n_eff = np.maximum(n * dt / tau_c, 4.0)
    return np.arctanh(np.clip(corr, -0.9999, 0.9999)) * np.sqrt(n_eff - 3.0)


def search_clock(u: Array, gyro: Array, accel: Array, tau: Array, R_WM: Array, p_WM: Array,
                 clock_shift: float, max_offset: float | None = None,
                 gravity: float = GRAVITY) -> ClockSearch:
    """Find the coarse ``t_d`` (see :class:`ClockSearch`).

    Args:
        u, gyro, accel: IMU times (s since the IMU origin) and samples.
        tau, R_WM, p_WM: mocap times (s since the mocap origin) and poses.
        clock_shift: ``(origin_imu - origin_mocap) * 1e-9``.
        max_offset: search only ``|t_d| <= max_offset`` (s, relative to the raw stamps).
        gravity: the |g| the specific-force signal assumes (m/s^2).

    Raises:
        ObservabilityError: no signal varies enough (no motion), or nothing in range.
    """
    dt = 1.0 / GRID_HZ
    sigs, sm = signals(u, gyro, accel, tau, R_WM, p_WM, dt, gravity)
    if not sigs:
        raise ObservabilityError(
            "cannot align the clocks: neither the angular speed nor the specific force varies "
            "(the body hardly moves); record a session with motion, or give --time-offset")
    # Every signal on one t_d axis: t_d = (start_m - clock_shift) - start_i + lag * dt.
    curves: dict[str, tuple[Array, Array]] = {}
    # The specific force's IMU side is one array for every up axis (alive in sigs): its
    # transforms and correlation time are computed once.
    x_spectra: dict[tuple[int, int, int], tuple[Array, ...]] = {}
    x_time: dict[int, float] = {}
    tau_cs: dict[str, float] = {}

    def curve(sg: ClockSignal) -> tuple[Array, Array, Array, float]:
        interrupt.check()
        corr, n, lags = _correlation(sg.x, sg.y, dt, x_spectra)
        if id(sg.x) not in x_time:
            x_time[id(sg.x)] = _correlation_time(sg.x, dt)
        tau_c = max(x_time[id(sg.x)], _correlation_time(sg.y, dt))
        return (sg.start_m - clock_shift) - sg.start_i + lags * dt, corr, n, tau_c

    # The first signal of each IMU-side array fills its caches; the rest run on the threads.
    first = [k for k, sg in enumerate(sigs) if all(sigs[j].x is not sg.x for j in range(k))]
    rest = [k for k in range(len(sigs)) if k not in first]
    done = dict(zip(first, [curve(sigs[k]) for k in first], strict=True))
    done.update(zip(rest, map_blocks(curve, [sigs[k] for k in rest]), strict=True))
    for k, sg in enumerate(sigs):
        td, corr, n, tau_c = done[k]
        tau_cs[sg.name] = tau_c
        curves[sg.name] = (td, _statistic(corr, n, tau_c, dt))
    # Specific force: keep the up axis whose curve has the highest peak.
    force = {k: v for k, v in curves.items() if k.startswith("specific force")}
    if force:
        best = max(force, key=lambda k: np.nanmax(force[k][1]))
        for k in force:
            if k != best:
                del curves[k]
    names = tuple(curves)
    lo = max(float(v[0][0]) for v in curves.values())
    hi = min(float(v[0][-1]) for v in curves.values())
    td = np.arange(np.ceil(lo / dt), np.floor(hi / dt) + 1) * dt
    stack = np.stack([np.interp(td, t, np.nan_to_num(c, nan=-1e6)) for t, c in curves.values()])
    valid = np.all(stack > -1e5, axis=0)
    z = stack.sum(axis=0) / np.sqrt(len(curves))
    if max_offset is not None:
        valid &= np.abs(td) <= max_offset
        if not np.any(valid):
            raise ObservabilityError(
                f"no clock offset within --max-offset {max_offset:g} s leaves enough overlap of "
                "the two streams; widen --max-offset or check the files")
    used = [sg for sg in sigs if sg.name in curves]
    restricted = (lo <= 0.0 <= hi) and max_offset is None  # one epoch: near zero first
    found = _peak(td, z, valid & (np.abs(td) <= SAME_EPOCH_RANGE_S)) if restricted else None
    if found is None or not found.resolved:
        restricted, found = False, _peak(td, z, valid)
    fine = _fine_peak(used, tau_cs, found.time_offset, clock_shift, dt)
    return _with_curve(replace(found, time_offset=fine), names, restricted, td, z, sm)


def _fine_peak(sigs: list[ClockSignal], tau_c: dict[str, float], t_d: float,
               clock_shift: float, dt: float) -> float:
    """The combined statistic's peak within a grid step of ``t_d``, at tenths of a step: the
    IMU side interpolated at each offset, usable points only. (On the grid, the curves of
    smooth, slowly varying signals have flat tops that a parabola through three points
    places off by several milliseconds.)"""
    offsets = t_d + np.arange(-10, 11) * (dt / 10.0)

    def scores(sg: ClockSignal) -> Array:  # one signal's, on the threads
        out = np.zeros(len(offsets))
        t_y = sg.start_m + np.arange(len(sg.y)) * dt
        for j, offset in enumerate(offsets):  # one offset at a time: no (offsets x n) arrays
            pos = (t_y - clock_shift - offset - sg.start_i) / dt
            k = np.clip(np.floor(pos).astype(int), 0, len(sg.x) - 2)
            a = pos - k
            ok = (pos >= 0) & (pos <= len(sg.x) - 1) & sg.y_ok & sg.x_ok[k] & sg.x_ok[k + 1]
            xi = (1.0 - a[ok]) * sg.x[k[ok]] + a[ok] * sg.x[k[ok] + 1]
            r = _pearson(xi, sg.y[ok])
            n_eff = max(ok.sum() * dt / tau_c[sg.name], 4.0)
            out[j] = np.arctanh(np.clip(r, -0.9999, 0.9999)) * np.sqrt(n_eff - 3.0)
        return out

    score = np.zeros(len(offsets))
    for part in map_blocks(scores, sigs):  # summed in the signals' order
        score += part
    return _refine(offsets, score, int(np.argmax(score)))


def _pearson(a: Array, b: Array) -> float:
    if len(a) < 3:
        return 0.0
    a, b = a - a.mean(), b - b.mean()
    den = float(np.sqrt(np.sum(a * a) * np.sum(b * b)))
    return float(np.sum(a * b) / den) if den > 0 else 0.0


def _refine(td: Array, zz: Array, k: int) -> float:
    """Sub-step position of the peak at index ``k`` (parabola through three points)."""
    frac = 0.0
    if 0 < k < len(zz) - 1 and np.isfinite(zz[k - 1]) and np.isfinite(zz[k + 1]):
        a, b, c = zz[k - 1], zz[k], zz[k + 1]
        den = a - 2 * b + c
        if den < 0:
            frac = 0.5 * (a - c) / den
    step = float(td[1] - td[0]) if len(td) > 1 else 0.0
    return float(td[k] + frac * step)


def _peak(td: Array, z: Array, use: NDArray[np.bool_]) -> ClockSearch:
    zz = np.where(use, z, -np.inf)
    k = int(np.argmax(zz))
    step = float(td[1] - td[0]) if len(td) > 1 else 0.0
    # Other peaks: local maxima further than the separation from the best.
    peaks = peaks_apart(np.where(np.isfinite(zz), zz, -1e9),
                        max(1, int(PEAK_SEPARATION_S / max(step, 1e-9))))
    far = [p for p in peaks if abs(td[p] - td[k]) > PEAK_SEPARATION_S and np.isfinite(zz[p])]
    far.sort(key=lambda p: -zz[p])
    second = far[0] if far else None
    margin = float(zz[k] - zz[second]) if second is not None else float(zz[k])
    cands = [(_refine(td, zz, p), float(zz[p])) for p in [k, *far[:3]]]
    return ClockSearch(cands[0][0], (), float(zz[k]), margin,
                       None if second is None else cands[1][0], False, candidates=tuple(cands))


def _with_curve(found: ClockSearch, names: tuple[str, ...], restricted: bool, td: Array,
                z: Array, sm: Smoothing, max_points: int = 4000) -> ClockSearch:
    """The search result with the signals used and a decimated curve for reports."""
    k = max(1, len(td) // max_points)
    return ClockSearch(found.time_offset, names, found.peak_z, found.margin_z,
                       found.second_offset, restricted, td[::k].copy(), z[::k].copy(),
                       found.candidates, smoothing=sm)
