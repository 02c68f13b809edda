"""IMU noise characterisation from a long static log by overlapping Allan deviation.

Per axis, the overlapping Allan deviation (``allantools.oadev``, octave-spaced ``tau``) is fitted
in the variance domain with the three-term model

    sigma^2(tau) = N^2 / tau + B^2 (2 ln 2 / pi) + K^2 tau / 3,

white noise ``N`` (slope -1/2), bias instability ``B`` (flat floor ``0.664 B``) and rate random
walk ``K`` (slope +1/2), with non-negative coefficients (NNLS). Each point is weighted by the
confidence of its Allan variance, ``sigma^2 sqrt(2 / edf)``, with the equivalent degrees of
freedom of the noise type that dominates there (NIST SP 1065 formulas); the weights use the
model, refitted a few times, because weighting by the measured values biases the fit low.

``N`` equals the fitted -1/2 line read at ``tau = 1 s``, ``K`` the +1/2 line read at
``tau = 3 s``. ``B`` is reported as the classic read-out ``min(adev) / 0.664`` (of the fitted
curve, an upper bound when the other terms still contribute at the minimum; the raw curve's
minimum is kept too) and as the fitted flicker term, which is dropped (0) when the data do not
need it.

The Kalibr ``imu.yaml`` keys carry the mean over the three axes (``aggregate="mean"``) or the
largest (``"max"``, conservative); the result classes live in
:mod:`mocap_calib.core.intrinsics.noise_result`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import allantools
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import nnls

from mocap_calib.core.intrinsics.noise_result import AllanResult, SensorNoise
from mocap_calib.core.model import rest
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.core.policy import GAP_FACTOR, gap_threshold
from mocap_calib.errors import InputError, ObservabilityError

Array = NDArray[np.float64]

_C_B = 2.0 * np.log(2.0) / np.pi  # Allan variance of flicker noise per B^2

#: Shortest log accepted at all (white noise needs minutes; the random walk hours).
MIN_DURATION_S = 600.0

#: Factor on the fit's 1-sigma for the correlation between octaves: in Monte Carlo runs
#: (40 seeds, 20 min to 2 h, ADIS16448 noise) the scatter of N and K was 1.4-2.4x the sigma
#: of an independent-points fit.
_CORRELATION_INFLATION = 2.0

#: Relative 1-sigma above which the random walk counts as not resolved.
MAX_RW_REL_SIGMA = 0.3

#: Motion detection thresholds for a static log.
_MOVING_VAR_RATIO = 10.0  # block accel variance vs. the log's median block variance
_MOVING_FRACTION = 0.01  # fraction of moving blocks tolerated
_MAX_TILT_DEG = 15.0  # gravity direction change (accel random walk alone can do ~5 deg in 6 h)
_MAX_GYRO_DEV = 0.05  # rad/s, block-mean gyro deviation from the median
_MAX_GYRO_MEAN = 0.1  # rad/s, a median rate larger than any usable gyro bias
#: Stamps that jitter this much (fraction of periods off by 10 %) are resampled; beyond, the
#: log is refused as not uniformly sampled.
MAX_JITTER_FRACTION = 0.2


# --------------------------------------------------------------------------------------------
# Checks
# --------------------------------------------------------------------------------------------

def _check_rate(imu: ImuSamples, rate_hz: float | None) -> float:
    if len(imu) < 2:
        raise InputError(f"{imu.source}: fewer than 2 samples")
    dt = np.diff(imu.t)
    if np.any(dt <= 0):
        row = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise InputError(f"{imu.source}: timestamps are not strictly increasing at sample "
                         f"{row}; sort the log by time and drop duplicate stamps")
    med = float(np.median(dt))
    rate = 1.0 / med
    if not 1.0 <= rate <= 10000.0:
        raise InputError(f"{imu.source}: sample rate {rate:.3g} Hz is outside 1-10000 Hz; "
                         "check the timestamp unit (nanoseconds expected)")
    if rate_hz is not None and abs(rate_hz - rate) > 0.05 * rate:
        raise InputError(f"{imu.source}: rate_hz={rate_hz:g} but the timestamps give "
                         f"{rate:.4g} Hz; pass the true rate or leave it out")
    # Gaps are handled (the log is split at them); single dropped samples (periods of two
    # steps) are not, and stamps that jitter are resampled (see uniform()).
    jitter, dropped = _irregular(dt, med)
    if dropped > 0.01 or jitter > MAX_JITTER_FRACTION:
        what = (f"{100 * dropped:.1f} % of the sample periods are two steps long (dropped "
                "samples)" if dropped > 0.01 else f"{100 * jitter:.1f} % of the sample "
                f"periods differ from {1e3 * med:.3g} ms by more than 10 %")
        raise InputError(f"{imu.source}: {what}; Allan deviation needs uniform sampling: fix "
                         "dropped samples or resample the log")
    return rate


def _irregular(dt: Array, med: float) -> tuple[float, float]:
    """Of the periods that are not gaps: the fraction off by more than 10 % from a whole
    number of steps (jitter), and the fraction of two steps (a dropped sample)."""
    r = dt[dt <= GAP_FACTOR * med] / med
    return (float(np.mean(np.abs(r - np.round(r)) > 0.1)),
            float(np.mean((np.round(r) >= 2) & (np.abs(r - np.round(r)) <= 0.1))))


def uniform(imu: ImuSamples, rate: float) -> tuple[ImuSamples, bool]:
    """The log on a uniform grid within each gap-free stretch when its stamps jitter (more than
    1 % of the periods off by 10 %: flight-controller logs); linear interpolation. Returns the
    samples and whether they were resampled."""
    dt = np.diff(imu.t)
    if _irregular(dt, float(np.median(dt)))[0] <= 0.01:
        return imu, False
    ts, gs, acs = [], [], []
    for sg in segments_of(imu.t):
        t = imu.t[sg]
        grid = t[0] + np.arange(int((t[-1] - t[0]) * rate) + 1) / rate
        ts.append(grid)
        gs.append(np.stack([np.interp(grid, t, imu.gyro[sg, i]) for i in range(3)], axis=1))
        acs.append(np.stack([np.interp(grid, t, imu.accel[sg, i]) for i in range(3)], axis=1))
    return ImuSamples(np.concatenate(ts), np.concatenate(gs), np.concatenate(acs),
                      imu.time_origin_ns, imu.source), True


def _check_static(imu: ImuSamples, rate: float) -> None:
    """Raise if the log shows motion: accel variance bursts, tilt changes or rotation."""
    blk = max(10, int(round(rate)))  # 1 s blocks
    nb = len(imu) // blk
    if nb < 10:
        return
    var = np.linalg.norm(rest.block_variances(imu.accel, blk), axis=1)
    floor = float(np.median(var))
    moving = var > _MOVING_VAR_RATIO * floor
    fix = "record the IMU resting on a stable surface, or crop the moving part"
    if moving.mean() > _MOVING_FRACTION:
        first = float(imu.t[int(np.argmax(moving)) * blk])
        raise ObservabilityError(
            f"{imu.source}: the log is not static: {100 * moving.mean():.1f} % of 1 s windows "
            f"(first at t={first:.0f} s) have accel variance >{_MOVING_VAR_RATIO:g}x the "
            f"noise floor; {fix}")
    am = rest.block_means(imu.accel, blk)
    dirs = am / np.linalg.norm(am, axis=1, keepdims=True)
    ref = np.median(dirs, axis=0)
    ref /= np.linalg.norm(ref)
    tilt = float(np.degrees(np.max(np.arccos(np.clip(dirs @ ref, -1.0, 1.0)))))
    if tilt > _MAX_TILT_DEG:
        raise ObservabilityError(f"{imu.source}: the log is not static: the gravity direction "
                                 f"changes by {tilt:.1f} deg; {fix}")
    gm = rest.block_means(imu.gyro, blk)
    med = np.median(gm, axis=0)
    if float(np.linalg.norm(med)) > _MAX_GYRO_MEAN:
        raise ObservabilityError(f"{imu.source}: the log is not static: the mean gyro rate is "
                                 f"{np.degrees(np.linalg.norm(med)):.1f} deg/s, more than a "
                                 f"gyro bias; {fix}")
    dev = np.linalg.norm(rest.median_deviation(gm), axis=1) > _MAX_GYRO_DEV
    if dev.mean() > _MOVING_FRACTION:
        first = float(imu.t[int(np.argmax(dev)) * blk])
        raise ObservabilityError(f"{imu.source}: the log is not static: the gyro shows "
                                 f"rotation in {100 * dev.mean():.1f} % of 1 s windows (first "
                                 f"at t={first:.0f} s); {fix}")


# --------------------------------------------------------------------------------------------
# Fit
# --------------------------------------------------------------------------------------------

def _edf(n: int, m: Array, alpha: Array) -> Array:
    """Equivalent degrees of freedom of the overlapping Allan variance (NIST SP 1065)."""
    out = np.empty(len(m))
    for i, (mi, a) in enumerate(zip(m, alpha, strict=True)):
        if a == -1 and mi < 2:
            a = 0  # the flicker formula needs m >= 2
        out[i] = allantools.edf_simple(n + 1, float(mi), int(a))
    return np.maximum(out, 1.0)


@dataclass(frozen=True)
class _AxisFit:
    coef: Array  # N^2, B^2, K^2
    cov: Array  # (3, 3), zero rows/cols for coefficients at the bound
    chi2: float
    avar_sigma: Array


def _fit_axis(tau: Array, avar: Array, m: Array, n: int) -> _AxisFit:
    A = np.stack([1.0 / tau, np.full_like(tau, _C_B), tau / 3.0], axis=1)
    fit = _fit_terms(A, avar, m, n, np.ones(3, dtype=bool))
    if 0 < fit.coef[1] < 2.0 * np.sqrt(fit.cov[1, 1]):
        # A flicker term the data do not need only trades with the other two: drop it.
        fit = _fit_terms(A, avar, m, n, np.array([True, False, True]))
    return fit


def _fit_terms(A_all: Array, avar: Array, m: Array, n: int, use: NDArray[np.bool_]) -> _AxisFit:
    A = A_all * use
    tau = A_all[:, 2] * 3.0
    ref = avar.copy()
    coef = np.zeros(3)
    sig = ref
    for _ in range(4):
        # Noise type that dominates each point, for its degrees of freedom.
        terms = A * coef if np.any(coef > 0) else A * np.array([avar[0] * tau[0], 0.0, 0.0])
        alpha = np.array([0, -1, -2])[np.argmax(terms, axis=1)]
        edf = _edf(n, m, alpha)
        sig = ref * np.sqrt(2.0 / edf)
        coef, _ = nnls(A / sig[:, None], avar / sig)
        model = A @ coef
        ref = np.where(model > 0, model, avar)
    active = coef > 0
    Aw = A[:, active] / sig[:, None]
    dof = len(tau) - int(active.sum())
    chi2 = float(np.sum(((avar - A @ coef) / sig) ** 2)) / dof if dof > 0 else float("nan")
    cov = np.zeros((3, 3))
    if active.any():
        sub = np.linalg.pinv(Aw.T @ Aw)
        # The fit treats the octaves as independent, but overlapping Allan variances at
        # neighbouring octaves are correlated; never trust it more than its scatter says.
        sub *= max(1.0, chi2) if np.isfinite(chi2) else 1.0
        sub *= _CORRELATION_INFLATION**2
        cov[np.ix_(active, active)] = sub
    return _AxisFit(coef, cov, chi2, sig)


def segments_of(t: Array) -> list[slice]:
    """The gap-free stretches of sample times ``t`` (the gap rule of ``core.policy``)."""
    cuts = np.flatnonzero(np.diff(t) > gap_threshold(t)) + 1
    edges = [0, *cuts.tolist(), len(t)]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def _oadev(x: Array, segs: list[slice], rate: float, ms: Array) -> tuple[Array, Array]:
    """Overlapping Allan variance at ``ms`` samples over the gap-free segments combined: each
    segment's variance weighted by its number of overlapping terms. Returns (avar, terms)."""
    num = np.zeros(len(ms))
    terms = np.zeros(len(ms))
    for sg in segs:
        y = x[sg]
        ok = ms * 2 < len(y)
        if not ok.any() or np.ptp(y) == 0:
            continue
        t_out, adev, _, ns = allantools.oadev(y, rate=rate, data_type="freq",
                                              taus=ms[ok] / rate)
        m_out = np.round(np.asarray(t_out, dtype=float) * rate)
        idx = np.searchsorted(ms, m_out)
        num[idx] += np.asarray(ns, dtype=float) * np.asarray(adev, dtype=float) ** 2
        terms[idx] += np.asarray(ns, dtype=float)
    return np.where(terms > 0, num / np.maximum(terms, 1.0), np.nan), terms


def _analyse(x: Array, rate: float, sensor: str, tau_min_s: float | None,
             tau_max_fraction: float, segs: list[slice] | None = None) -> SensorNoise:
    segs = segs or [slice(0, len(x))]
    n = sum(sg.stop - sg.start for sg in segs)
    longest = max(sg.stop - sg.start for sg in segs)
    m_max = int(min(n * tau_max_fraction, (longest - 1) / 2))
    m_min = max(1, int(np.ceil((tau_min_s or 0.0) * rate)))
    ms = 2 ** np.arange(0, int(np.log2(max(m_max, 1))) + 1)
    ms = ms[(ms >= m_min) & (ms <= m_max)]
    if len(ms) < 5:
        raise ObservabilityError(f"only {len(ms)} averaging times between {m_min / rate:g} s "
                                 f"and {m_max / rate:g} s; record a longer static log")
    N, K, Bf, sN, sK, bi, bi_raw, tmin, chi2 = (np.zeros(3) for _ in range(9))
    adev_all, sig_all, fit_all = [], [], []
    tau = ms / rate
    for ax in range(3):
        if np.ptp(x[:, ax]) == 0:
            raise ObservabilityError(f"the {sensor} {'xyz'[ax]} axis is constant over the whole "
                                     "log (dead, saturated or not logged); check the sensor")
        avar, _ = _oadev(x[:, ax], segs, rate, ms.astype(float))
        adev = np.sqrt(avar)
        m = ms.astype(float)
        fit = _fit_axis(tau, avar, m, n)
        c, cov = fit.coef, fit.cov
        N[ax], Bf[ax], K[ax] = np.sqrt(c)
        sN[ax] = np.sqrt(cov[0, 0]) / (2 * N[ax]) if N[ax] > 0 else np.inf
        sK[ax] = np.sqrt(cov[2, 2]) / (2 * K[ax]) if K[ax] > 0 else np.inf
        model = np.sqrt(np.stack([1.0 / tau, np.full_like(tau, _C_B), tau / 3.0], 1) @ c)
        # The minimum of the fitted curve: the raw curve's minimum picks its noisiest low
        # point at long tau, where few independent intervals remain.
        i_min = int(np.argmin(model))
        bi[ax] = model[i_min] / 0.664
        bi_raw[ax] = float(np.min(adev)) / 0.664
        tmin[ax] = tau[i_min]
        chi2[ax] = fit.chi2
        adev_all.append(adev)
        # d(adev) = d(avar) / (2 adev).
        sig_all.append(fit.avar_sigma / (2.0 * np.maximum(adev, 1e-300)))
        fit_all.append(model)
    resolved = (K > 0) & (sK < MAX_RW_REL_SIGMA * K)
    return SensorNoise(
        sensor=sensor, noise_density=N, random_walk=np.where(resolved, K, np.nan),
        random_walk_fit=K, bias_instability=bi, bias_instability_raw=bi_raw,
        bias_instability_fit=Bf, noise_density_sigma=sN,
        random_walk_sigma=sK, random_walk_resolved=resolved, tau_at_minimum=tmin, tau=tau,
        adev=np.array(adev_all), adev_sigma=np.array(sig_all), adev_fit=np.array(fit_all),
        fit_chi2=chi2)


def _hours_needed(s: SensorNoise, duration_s: float) -> float:
    """Rough log length (h) at which the random walk would be resolved on every axis."""
    need = 2.0 * duration_s
    for ax in np.flatnonzero(~s.random_walk_resolved):
        K = float(s.random_walk_fit[ax])
        rel = float(s.random_walk_sigma[ax]) / K if K > 0 else np.inf
        if np.isfinite(rel):
            # Once the +1/2 slope shows, the relative precision improves as 1/sqrt(duration);
            # aim at half the acceptance limit.
            need = max(need, duration_s * (rel / (0.5 * MAX_RW_REL_SIGMA)) ** 2)
        else:
            # Not seen at all: K is below the value that would explain the last point alone,
            # so the crossover with the white noise is at least tau_c; ~100 tau_c are needed.
            K_ub = float(np.sqrt(3.0 * s.adev[ax, -1] ** 2 / s.tau[-1]))
            tau_c = np.sqrt(3.0) * float(s.noise_density[ax]) / max(K_ub, 1e-300)
            need = max(need, 100.0 * tau_c)
    return need / 3600.0


def characterise_noise(
    imu: ImuSamples,
    *,
    rate_hz: float | None = None,
    aggregate: Literal["mean", "max"] = "mean",
    tau_min_s: float | None = None,
    tau_max_fraction: float = 1.0 / 6.0,
    require_random_walk: bool = True,
    check_static: bool = True,
    unresolved_fix: str = "pass require_random_walk=False",
) -> AllanResult:
    """Allan-deviation noise model (white noise, random walk, bias instability) per axis.

    Args:
        imu: a long static log (hours for the random walk; the IMU must not move).
        rate_hz: expected sample rate; checked against the timestamps when given.
        aggregate: how the Kalibr keys combine the axes: ``"mean"`` or ``"max"``.
        tau_min_s: shortest averaging time fitted (default: one sample). Raise it (e.g. to
            ``4 / rate``) when the IMU's internal low-pass filter bends the curve down at the
            shortest ``tau``.
        tau_max_fraction: longest averaging time as a fraction of the log (the last points
            have few degrees of freedom; they are weighted accordingly).
        require_random_walk: raise when the log is too short to resolve the random walk;
            otherwise report it as NaN (``null`` in ``to_dict``).
        check_static: check that the log shows no motion.
        unresolved_fix: how the message for an unresolved random walk names the way to
            accept it (a CLI names its option).

    Returns:
        The noise parameters per axis, the Kalibr keys via ``to_dict()``, and the curves.

    Raises:
        InputError: bad timestamps or rate.
        ObservabilityError: the log is too short, moves, or does not resolve the random walk.
    """
    if aggregate not in ("mean", "max"):
        raise InputError(f"aggregate='{aggregate}': use 'mean' or 'max'")
    if not 0.0 < tau_max_fraction <= 0.5:
        raise InputError(f"tau_max_fraction={tau_max_fraction}: must be in (0, 0.5]")
    rate = _check_rate(imu, rate_hz)
    imu, _ = uniform(imu, rate)
    segs = segments_of(imu.t)
    duration = float(sum(imu.t[sg.stop - 1] - imu.t[sg.start] for sg in segs))
    if duration < MIN_DURATION_S:
        raise ObservabilityError(
            f"{imu.source}: static log is {duration / 60:.1f} min long; Allan analysis needs "
            f"at least {MIN_DURATION_S / 60:.0f} min for the white noise and typically 2-4 h "
            "for the random walk")
    if check_static:
        _check_static(imu, rate)
    gyro = _analyse(imu.gyro, rate, "gyroscope", tau_min_s, tau_max_fraction, segs)
    accel = _analyse(imu.accel, rate, "accelerometer", tau_min_s, tau_max_fraction, segs)
    if require_random_walk:
        for s in (gyro, accel):
            if not np.all(s.random_walk_resolved):
                axes = "".join("xyz"[i] for i in range(3) if not s.random_walk_resolved[i])
                hours = _hours_needed(s, duration)
                raise ObservabilityError(
                    f"{imu.source}: the {s.sensor} random walk ({axes}) is not resolved in "
                    f"this {duration / 3600:.2f} h log (the Allan deviation does not rise "
                    f"clearly by tau={s.tau[-1]:.0f} s); record at least {hours:.1f} h "
                    f"static, or {unresolved_fix}")
    return AllanResult(gyro, accel, rate, duration, len(imu), aggregate)
