"""Simulate what the IMU should have measured from the mocap poses, and compare.

The IMU pose ``T_WI = T_WM T_MI`` is interpolated with cubic splines (positions per axis,
quaternion components with a continuous sign) at the IMU sample times shifted by the clock
offset; the splines' derivatives give the true angular rate ``w`` and specific force ``f``, which
the calibrated measurement model turns into predicted raw gyro and accel samples.

Differentiated mocap noise is large at high frequencies, so the comparison is made after the
same zero-phase low-pass filter on measured and predicted signals, and the *noise floor* is what
the same processing gives for noise alone: IMU white noise plus the bias random walk's wander
between the estimated bias knots, plus the mocap noise pushed through the same splines. The
floor is computed by Monte Carlo with a fixed seed (deterministic).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.diagnosis.filters import ar1, butter_lowpass, sosfiltfilt, welch
from mocap_calib.core.diagnosis.spline import CubicSpline
from mocap_calib.core.model import so3
from mocap_calib.core.model.imu_model import Intrinsics, accel_lag, forward, imu_times
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.policy import gap_threshold
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.result.series import ImuPrediction, ResidualAnalysis
from mocap_calib.core.result.state import ModelState
from mocap_calib.core.threads import map_blocks

Array = NDArray[np.float64]


def _pose_splines(tau: Array, R_WI: Array, p_WI: Array,
                  smooth_hz: float) -> tuple[CubicSpline, CubicSpline]:
    q = so3.rotmat_to_quat(R_WI)
    # Continuous sign so the component splines do not jump between q and -q.
    flip = np.cumprod(np.where(np.einsum("ni,ni->n", q[1:], q[:-1]) < 0, -1.0, 1.0))
    q[1:] *= flip[:, None]
    p = p_WI
    rate = 1.0 / float(np.median(np.diff(tau)))
    if smooth_hz < 0.45 * rate and len(tau) > 30:
        sos = butter_lowpass(4, smooth_hz, rate)
        q = sosfiltfilt(sos, q)
        p = sosfiltfilt(sos, p_WI)
    return CubicSpline(tau, q), CubicSpline(tau, p)


def _rate_and_accel(qs: CubicSpline, ps: CubicSpline,
                    t: Array) -> tuple[Array, Array, Array, Array]:
    """Attitude, body rate, world acceleration and body angular acceleration at ``t``."""
    q = qs(t)
    dq = qs(t, 1)
    n2 = np.einsum("ni,ni->n", q, q)
    qc = q * np.array([1.0, -1.0, -1.0, -1.0])
    w = 2.0 * so3.quat_multiply(qc, dq)[:, 1:] / n2[:, None]
    # d/dt of 2 vec(q* q') / |q|^2 (vec(q'* q') = 0).
    dn2 = 2.0 * np.einsum("ni,ni->n", q, dq)
    alpha = (2.0 * so3.quat_multiply(qc, qs(t, 2))[:, 1:] - w * dn2[:, None]) / n2[:, None]
    R = so3.quat_to_rotmat(q)
    return R, w, ps(t, 2), alpha


def gap_free_segments(tau: Array, gap: float, min_length: float) -> list[tuple[float, float]]:
    """Mocap-time spans without gaps, at least ``min_length`` long."""
    breaks = np.flatnonzero(np.diff(tau) > gap) + 1
    out = []
    for seg in np.split(np.arange(len(tau)), breaks):
        if len(seg) > 4 and tau[seg[-1]] - tau[seg[0]] >= min_length:
            out.append((float(tau[seg[0]]), float(tau[seg[-1]])))
    return out


def predict_imu(s: PreparedSession, st: ModelState, min_segment: float = 3.0,
                mocap: tuple[Array, Array] | None = None, smooth_hz: float = 10.0) -> ImuPrediction:
    """Predict raw IMU samples from the mocap through the calibrated model.

    Args:
        s: prepared session.
        st: calibration and bias trajectory.
        min_segment: shorter gap-free mocap stretches are not used (s).
        mocap: optional replacement ``(R_WM, p_WM)`` (used to push noise through the splines).
        smooth_hz: zero-phase low-pass of the poses before differentiation. Differentiated
            mocap noise is huge at high frequencies; left in, it multiplies with the attitude
            noise in ``R^T (a - g)`` and leaks into every band.
    """
    R_WM, p_WM = (s.R_WM, s.p_WM) if mocap is None else mocap
    R_WI = R_WM @ st.R_MI
    p_WI = p_WM + R_WM @ st.p_MI
    spans = gap_free_segments(s.tau, s.gap, min_segment)
    timing = Intrinsics(np.zeros(3), np.zeros(3), st.effects, st.t_mid)
    # When each sample was taken (mocap clock): the clock effects move gyro and accel samples.
    tau_g = imu_times(st.model, timing, s.u) + st.delta
    lag = accel_lag(st.model, timing)
    idx_all: list[NDArray[np.int64]] = []
    parts: list[tuple[Array, ...]] = []
    imu_gap = gap_threshold(s.u)
    for a, b in spans:
        sel = (s.tau >= a) & (s.tau <= b)
        qs, ps = _pose_splines(s.tau[sel], R_WI[sel], p_WI[sel], smooth_hz)
        # IMU samples whose mocap time lies inside the span (margin for the lag).
        iu = np.flatnonzero((tau_g - lag > a + 0.01) & (tau_g > a + 0.01) & (tau_g < b - 0.01)
                            & (tau_g - lag < b - 0.01))
        # The filters and spectra need steady sampling: a stretch ends at an IMU gap too.
        for piece in np.split(iu, np.flatnonzero(np.diff(s.u[iu]) > imu_gap) + 1):
            if len(piece) < 10:
                continue
            R, w, a_W, alpha = _rate_and_accel(qs, ps, tau_g[piece])
            f = np.einsum("nji,nj->ni", R, a_W - st.g_W)
            Ra, wa, a_Wa, alpha_a = (R, w, a_W, alpha) if lag == 0.0 else _rate_and_accel(
                qs, ps, tau_g[piece] - lag)
            fa = f if lag == 0.0 else np.einsum("nji,nj->ni", Ra, a_Wa - st.g_W)
            idx_all.append(piece)
            parts.append((w, f, alpha, wa, fa, alpha_a))
    if not idx_all:
        empty = np.zeros((0, 3))
        return ImuPrediction(np.zeros(0), [], empty, empty, empty, empty, empty, empty)
    iu = np.concatenate(idx_all)
    w, f, alpha, wa, fa, alpha_a = (np.concatenate(x) for x in zip(*parts, strict=True))
    lengths = np.cumsum([0, *[len(i) for i in idx_all]])
    segments = [np.arange(lengths[i], lengths[i + 1]) for i in range(len(idx_all))]
    u = s.u[iu]
    gyro_pred, accel_pred = model_forward(st, w, f, u, alpha)
    if lag != 0.0:  # the accelerometer saw the motion `lag` earlier than the gyro
        _, accel_pred = model_forward(st, wa, fa, u, alpha_a)
    return ImuPrediction(u, segments, s.gyro[iu], s.accel[iu], gyro_pred, accel_pred, w, f)


def model_forward(st: ModelState, w: Array, f: Array, u: Array,
                  alpha: Array | None = None) -> tuple[Array, Array]:
    """Raw measurements the model predicts for true ``w``, ``f`` (and angular acceleration
    ``alpha``) at IMU times ``u``."""
    b = st.bias_at(u + st.delta)
    return forward(st.model, Intrinsics(b[:, 0:3], b[:, 3:6], st.effects, st.t_mid), w, f, u,
                   alpha)


def lowpass(x: Array, rate: float, cutoff: float, segments: list[NDArray[np.int64]]) -> Array:
    """Zero-phase Butterworth low-pass, applied within each segment."""
    sos = butter_lowpass(4, cutoff, rate)
    y = np.zeros_like(x)
    for seg in segments:
        y[seg] = sosfiltfilt(sos, x[seg])
    return y


def interior(n: int, segments: list[NDArray[np.int64]], rate: float,
             cutoff: float) -> NDArray[np.bool_]:
    """Samples away from segment ends, where the filter's and the splines' edge transients
    have died out (two filter time constants)."""
    keep = np.zeros(n, bool)
    margin = int(np.ceil(2.0 * rate / cutoff))
    for seg in segments:
        if len(seg) > 2 * margin:
            keep[seg[margin:-margin]] = True
    return keep


def _welch(x: Array, rate: float, segments: list[NDArray[np.int64]]) -> tuple[Array, Array]:
    nper = int(min(1024, max(64, min(len(seg) for seg in segments) // 2)))
    psds = []
    weights = []
    freq = np.zeros(0)
    for seg in segments:
        if len(seg) < nper:
            continue
        freq, p = welch(x[seg], rate, nper)
        psds.append(p)
        weights.append(len(seg))
    if not psds:
        return np.zeros(1), np.zeros((1, 3))
    return freq, np.average(np.stack(psds), axis=0, weights=np.asarray(weights, float))


def analyse_residuals(s: PreparedSession, st: ModelState, noise: NoiseModel,
                      pred: ImuPrediction | None = None, cutoff_hz: float = 2.0,
                      bias_knot_spacing: float | None = None, seed: int = 0,
                      floor_of: ResidualAnalysis | None = None) -> ResidualAnalysis:
    """Residuals of the calibrated model against the measurements, with their noise floor
    (``floor_of``: that analysis' floor, for a nearby model under the same noise model,
    instead of a Monte Carlo of its own)."""
    pred = pred or predict_imu(s, st)
    rate = s.imu_rate
    cutoff = min(cutoff_hz, 0.45 * min(rate, s.mocap_rate))
    rg = pred.gyro_meas - pred.gyro_pred
    ra = pred.accel_meas - pred.accel_pred
    rg_lp = lowpass(rg, rate, cutoff, pred.segments)
    ra_lp = lowpass(ra, rate, cutoff, pred.segments)
    n = len(pred.u)
    keep = interior(n, pred.segments, rate, cutoff)
    if len(s.removed_tau):
        # Around removed mocap spikes the neighbouring poses are suspect too, and the splines
        # bridge the hole: leave a filter time constant on each side out of the comparison.
        t_m = pred.u + st.delta
        near = np.abs(t_m[:, None] - s.removed_tau[None, :]).min(axis=1) if len(
            s.removed_tau) < 64 else _nearest_distance(t_m, s.removed_tau)
        keep &= near > 1.0 / cutoff

    def rms(x: Array) -> Array:
        return np.sqrt(np.mean(x[keep] ** 2, axis=0))

    if floor_of is None:
        spacing = bias_knot_spacing or (float(np.median(np.diff(st.bias_t)))
                                        if len(st.bias_t) > 1 else pred.u[-1] - pred.u[0])
        floor2, parts, psd_floor = _noise_floor(s, st, pred, noise, (rate, cutoff, spacing),
                                                rms, np.random.default_rng(seed))
    freq, pg = _welch(rg, rate, pred.segments)
    _, pa = _welch(ra, rate, pred.segments)
    if floor_of is not None:
        floor2 = np.r_[floor_of.gyro_floor, floor_of.accel_floor] ** 2
        parts = dict(floor_of.floor_parts)
        psd_floor = np.hstack([floor_of.gyro_psd_floor, floor_of.accel_psd_floor])
        if len(floor_of.freq) != len(freq) or not np.allclose(floor_of.freq, freq):
            # Other segments (another clock offset): the floor's spectrum at these frequencies.
            psd_floor = np.column_stack([np.interp(freq, floor_of.freq, c)
                                         for c in psd_floor.T])
    pgf, paf = psd_floor[:, 0:3], psd_floor[:, 3:6]
    return ResidualAnalysis(cutoff, rms(rg_lp), rms(ra_lp), np.sqrt(floor2[0:3]),
                            np.sqrt(floor2[3:6]), freq, pg, pa, pgf, paf, rg_lp, ra_lp,
                            parts, pred.u + st.delta, keep)


def _noise_floor(s: PreparedSession, st: ModelState, pred: ImuPrediction, noise: NoiseModel,
                 bands: tuple[float, float, float], rms: Callable[[Array], Array],
                 rng: np.random.Generator) -> tuple[Array, dict[str, Array], Array]:
    """Noise alone through the same processing, averaged over a few draws so that the floor's
    own Monte Carlo scatter stays near 2 %: its mean square per axis (gyro then accel), per
    source (RMS), and its Welch PSD. ``bands``: IMU rate, low-pass cutoff, knot spacing."""
    rate, cutoff, spacing = bands
    n = len(pred.u)
    draws = 4

    def draw() -> tuple[Array, Array, Array, Array]:
        white = np.concatenate([
            rng.normal(0.0, noise.gyroscope_noise_density * np.sqrt(rate), (n, 3)),
            rng.normal(0.0, noise.accelerometer_noise_density * np.sqrt(rate), (n, 3))], axis=1)
        walk = _bias_walk_residual(rng, pred, noise, spacing)
        if st.bias_sigma is not None and len(st.bias_t) > 1:
            # The estimated knots are off by their own uncertainty, interpolated in between.
            err = rng.normal(size=st.bias_sigma.shape) * st.bias_sigma
            walk += np.stack([np.interp(pred.u + st.delta, st.bias_t, err[:, i])
                              for i in range(6)], axis=1)
        rot = mocap_noise(rng, s.tau, noise.mocap_rotation_sigma, noise)
        return white, walk, rot, mocap_noise(rng, s.tau, noise.mocap_position_sigma, noise)

    def through(draw: tuple[Array, Array, Array, Array]) -> tuple[list[Array], Array, Array]:
        """A draw's mean squares per source and in all, and its PSD (no series kept)."""
        white, walk, rot, pos = draw
        pn = predict_imu(s, st, mocap=(s.R_WM @ so3.exp(rot), s.p_WM + pos))
        moc = -np.concatenate([pn.gyro_pred - pred.gyro_pred, pn.accel_pred - pred.accel_pred],
                              axis=1)
        del pn
        lps = [lowpass(x, rate, cutoff, pred.segments) for x in (white, walk, moc)]
        total = rms(lps[0] + lps[1] + lps[2]) ** 2
        return [rms(lp) ** 2 for lp in lps], total, _welch(white + walk + moc, rate,
                                                            pred.segments)[1]

    parts = {"white": np.zeros(6), "bias_walk": np.zeros(6), "mocap": np.zeros(6)}
    floor2 = np.zeros(6)
    psd_floor: Any = 0.0
    # The random parts are drawn in order (the seed fixes them), two draws at a time
    # processed on the threads and summed in order: the same numbers as one after the other.
    for _ in range(draws // 2):
        for squares, total, psd in map_blocks(through, [draw(), draw()]):
            for name, sq in zip(parts, squares, strict=True):  # linear: the parts add up
                parts[name] += sq / draws
            floor2 += total / draws
            psd_floor = psd_floor + psd / draws
    return floor2, {k: np.sqrt(v) for k, v in parts.items()}, psd_floor


def mocap_noise(rng: np.random.Generator, tau: Array, sigma: float,
                noise: NoiseModel) -> Array:
    """(M, 3) mocap noise of marginal ``sigma`` at times ``tau``: white plus, as the noise model
    says, a fraction correlated over ``mocap_noise_corr_time`` (AR(1), started stationary)."""
    white = rng.normal(0.0, sigma, (len(tau), 3))
    if not noise.mocap_correlated:
        return white
    rho = noise.mocap_noise_corr_fraction
    a = float(np.exp(-np.median(np.diff(tau)) / noise.mocap_noise_corr_time))
    e = rng.normal(0.0, sigma, (len(tau), 3))
    ar = ar1(e, a, float(np.sqrt(1.0 - a * a)))
    ar += np.outer(a ** np.arange(len(tau)), e[0] * (1.0 - np.sqrt(1.0 - a * a)))  # stationary
    return np.sqrt(1.0 - rho) * white + np.sqrt(rho) * ar


def _bias_walk_residual(rng: np.random.Generator, pred: ImuPrediction, noise: NoiseModel,
                        spacing: float) -> Array:
    """Bias random walk minus its piecewise-linear interpolation between knots ``spacing``
    apart: the part of the bias the estimated knot trajectory cannot follow. (n, 6)."""
    out = np.zeros((len(pred.u), 6))
    q = np.r_[np.full(3, noise.gyroscope_random_walk), np.full(3, noise.accelerometer_random_walk)]
    for seg in pred.segments:
        t = pred.u[seg]
        dt = np.diff(t, prepend=t[0])
        walk = np.cumsum(rng.normal(0.0, 1.0, (len(seg), 6)) * np.sqrt(dt)[:, None] * q, axis=0)
        knots_t = np.arange(t[0], t[-1] + spacing, spacing)
        lin = np.stack([np.interp(t, knots_t, np.interp(knots_t, t, walk[:, i]))
                        for i in range(6)], axis=1)
        out[seg] = walk - lin
    return out


def _nearest_distance(t: Array, ref: Array) -> Array:
    """Distance from every ``t`` to the nearest of the sorted times ``ref``."""
    j = np.clip(np.searchsorted(ref, t), 1, len(ref) - 1)
    return np.minimum(np.abs(t - ref[j - 1]), np.abs(t - ref[j]))
