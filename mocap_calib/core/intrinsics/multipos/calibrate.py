"""``calibrate_multipos``: static detector, threshold scan with the accelerometer fit, gyro bias
from the initial rest, gyroscope fit over the rotations, sigmas and the poorly-determined list."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.intrinsics.multipos.detector import Detector, check_timing, make_detector
from mocap_calib.core.intrinsics.multipos.fit import AccelFit, GyroFit, fit_accel, fit_gyro
from mocap_calib.core.intrinsics.multipos.params import (
    DISTINCT_DEG,
    LOWER,
    POOR_CONDITION,
    POOR_SIGMA,
    option,
    option_value,
)
from mocap_calib.core.intrinsics.multipos.prior import MultiposPrior
from mocap_calib.core.intrinsics.multipos.result import MultiposResult
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.errors import ConvergenceError, InputError, ObservabilityError

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]


def interval_stats(accel: Array, iv: IntArray) -> tuple[Array, Array]:
    """Mean accel of each interval and the 1-sigma of its norm from the in-interval noise."""
    means = np.empty((len(iv), 3))
    var_mean = np.empty((len(iv), 3))
    for k, (a, b) in enumerate(iv):
        x = accel[a:b + 1]
        means[k] = x.mean(axis=0)
        var_mean[k] = x.var(axis=0, ddof=1) / len(x)
    u = means / np.linalg.norm(means, axis=1, keepdims=True)
    sig = np.sqrt(np.sum(u * u * var_mean, axis=1))
    return means, np.maximum(sig, 1e-9)


def _distinct(dirs: Array) -> int:
    """Greedy count of gravity directions more than :data:`DISTINCT_DEG` apart."""
    cos_lim = np.cos(np.radians(DISTINCT_DEG))
    centres: list[Array] = []
    for d in dirs:
        if not centres or np.max(np.asarray(centres) @ d) < cos_lim:
            centres.append(d)
    return len(centres)


def _check_spread(dirs: Array, n: int) -> None:
    """Raise if the gravity directions cannot separate scale from bias on every axis."""
    fix = ("turn the IMU through orientations spread over the whole sphere, each axis "
           "pointing up and down in some of them")
    mean = dirs.mean(axis=0)
    if np.linalg.norm(mean) > 1e-9:
        m = mean / np.linalg.norm(mean)
        cone = float(np.degrees(np.max(np.arccos(np.clip(dirs @ m, -1.0, 1.0)))))
        if cone < 60.0:
            raise ObservabilityError(f"all {n} static orientations have gravity within "
                                     f"{cone:.0f} deg of one direction; {fix}")
    ev = np.linalg.eigvalsh(dirs.T @ dirs / len(dirs))
    if ev[0] < 0.02:
        raise ObservabilityError(f"the {n} static gravity directions lie in one plane (the "
                                 f"IMU was turned about one axis only); {fix}")


def _gyro_bias(gyro: Array, rate: float) -> tuple[Array, Array, float]:
    """Mean gyro, its 1-sigma and the white-noise density over a static stretch."""
    n = len(gyro)
    bias = gyro.mean(axis=0)
    sd_white = gyro.std(axis=0, ddof=1) / np.sqrt(n)
    # Block means catch correlated noise (random walk, flicker) the white estimate misses.
    nb = 10
    blk = n // nb
    blocks = gyro[:nb * blk].reshape(nb, blk, 3).mean(axis=1)
    sd_block = blocks.std(axis=0, ddof=1) / np.sqrt(nb)
    density = float(np.sqrt(np.mean(gyro.var(axis=0, ddof=1)) / rate))
    return bias, np.maximum(sd_white, sd_block), density


def _poor(name: str, sigma: Array, lower_only: bool = False) -> list[str]:
    out = []
    for i in range(3):
        for j in range(3):
            if lower_only and j > i:
                continue
            lim = POOR_SIGMA["scale"] if i == j else POOR_SIGMA["misalignment"]
            if not sigma[i, j] <= lim:
                kind = "scale" if i == j else "misalignment"
                out.append(f"{name}[{i}][{j}] ({kind}, sigma {sigma[i, j]:.2g})")
    return out


# --------------------------------------------------------------------------------------------
# Steps of calibrate_multipos
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Choice:
    """The threshold chosen by the scan and its accelerometer fit."""

    k: float
    intervals: IntArray
    fit: AccelFit
    n_distinct: int
    scan: list[dict[str, Any]]


def _check_options(imu: ImuSamples, init_static_s: float, window_s: float,
                   min_interval_s: float, gravity: float, min_orientations: int,
                   names: Mapping[str, str] | None) -> float:
    """Checks the options and the log's length; returns the sample rate."""
    if not 5.0 < gravity < 15.0:
        raise InputError(f"{option_value(names, 'gravity', gravity)}: give |g| in m/s^2, "
                         "e.g. 9.81")
    if not init_static_s > 0 or not window_s > 0 or not min_interval_s > 0:
        raise InputError(f"{option(names, 'init_static_s')}, {option(names, 'window_s')} and "
                         f"{option(names, 'min_interval_s')} must be positive")
    if min_orientations < 3:
        raise InputError(f"{option_value(names, 'min_orientations', min_orientations)}: must "
                         "be at least 3")
    rate = check_timing(imu)
    need = init_static_s + min_orientations * (min_interval_s + window_s + 1.0)
    if imu.duration < need:
        raise ObservabilityError(
            f"{imu.source}: log is {imu.duration:.0f} s long, too short for a multi-position "
            f"session (needs >= {need:.0f} s: {init_static_s:.0f} s at rest, then at least "
            f"{min_orientations} orientations held 2-4 s; Tedaldi recommends 36-50)")
    return rate


def _scan(det: Detector, accel: Array, thresholds: Sequence[float], min_orientations: int,
          gravity: float, prior: MultiposPrior | None) -> _Choice:
    """One accel fit per threshold multiple on interval sets that can determine it; the
    multiple whose reduced chi-square is indistinguishable from the best and that finds the
    most intervals wins."""
    scan: list[dict[str, Any]] = []
    fits: list[tuple[float, IntArray, AccelFit, int]] = []
    most, most_distinct = 0, 0
    spread_error: ObservabilityError | None = None
    for k in thresholds:
        iv = det.intervals(float(k))
        most = max(most, len(iv))
        entry: dict[str, Any] = {"k": float(k), "n_intervals": int(len(iv)), "chi2": None}
        scan.append(entry)
        if len(iv) < min_orientations:
            continue
        means, sig = interval_stats(accel, iv)
        dirs = means / np.linalg.norm(means, axis=1, keepdims=True)
        n_distinct = _distinct(dirs)
        most_distinct = max(most_distinct, n_distinct)
        if n_distinct < min_orientations:
            continue
        try:
            _check_spread(dirs, len(iv))
        except ObservabilityError as e:
            spread_error = e
            continue
        fit = fit_accel(means, sig, gravity, prior)
        if fit.ok:
            entry["chi2"] = fit.chi2 if fit.dof > 0 else None
            fits.append((float(k), iv, fit, n_distinct))
    if not fits:
        _no_fit(most, most_distinct, min_orientations, spread_error)
    ranked = [f for f in fits if f[2].dof > 0]
    if ranked:
        best = min(ranked, key=lambda f: f[2].chi2)[2]
        tol = best.chi2 * (1.0 + 2.0 * np.sqrt(2.0 / best.dof))
        k_best, iv, afit, n_distinct = max((f for f in ranked if f[2].chi2 <= tol),
                                           key=lambda f: (len(f[1]), -f[2].chi2))
    else:
        # Exactly determined (as many intervals as parameters): nothing to rank by.
        k_best, iv, afit, n_distinct = fits[0]
    return _Choice(k_best, iv, afit, n_distinct, scan)


def _no_fit(most: int, most_distinct: int, min_orientations: int,
            spread_error: ObservabilityError | None) -> None:
    """Raise the reason why no threshold gave a usable accelerometer fit."""
    if most < min_orientations:
        raise ObservabilityError(
            f"found {most} static orientations, need at least {min_orientations} distinct "
            f"ones (Tedaldi recommends 36-50); hold the IMU still for 2-4 s in more "
            f"orientations")
    if most_distinct < min_orientations:
        raise ObservabilityError(
            f"found {most} static intervals but only {most_distinct} distinct orientations "
            f"(gravity directions >{DISTINCT_DEG:.0f} deg apart), need at least "
            f"{min_orientations} (Tedaldi recommends 36-50); hold the IMU still for 2-4 s "
            f"in more, different orientations")
    if spread_error is not None:
        raise spread_error
    raise ConvergenceError("multipos: the accelerometer fit failed for every static "
                           "threshold; check that the accel is in m/s^2 and |g| is right")


def _gyro_bias_with_prior(gyro_init: Array, rate: float, prior: MultiposPrior | None
                          ) -> tuple[Array, Array, float]:
    """Gyro bias over the initial rest (w = 0 there), combined with a prior if given."""
    bg, bg_sd, density = _gyro_bias(gyro_init, rate)
    if prior is not None:
        v, s, used = prior.rows("gyro_bias")
        w_d, w_p = 1.0 / bg_sd**2, np.where(used, 1.0 / np.where(used, s, 1.0) ** 2, 0.0)
        bg = (w_d * bg + w_p * np.where(used, v, 0.0)) / (w_d + w_p)
        bg_sd = 1.0 / np.sqrt(w_d + w_p)
    return bg, bg_sd, density


def _fit_rotations(imu: ImuSamples, iv: IntArray, afit: AccelFit, gravity: float,
                   bg: Array, bg_sd: Array, density: float,
                   prior: MultiposPrior | None) -> GyroFit:
    """Gyro matrix from the rotations between consecutive static intervals."""
    means, sig_int = interval_stats(imu.accel, iv)
    M_a, b_a = afit.M, afit.b
    h = (means - b_a) @ np.linalg.inv(M_a).T
    u = h / np.linalg.norm(h, axis=1, keepdims=True)
    sig_dir = sig_int / gravity  # per-axis noise of the mean, as an angle
    starts, ends = iv[1:, 0], iv[:-1, 1]
    steps = starts - ends
    L = int(steps.max())
    idx = ends[:, None] + np.minimum(np.arange(L + 1)[None, :], steps[:, None])
    gyro_pad = imu.gyro[idx]
    dt_all = np.diff(imu.t)
    step_idx = ends[:, None] + np.minimum(np.arange(L)[None, :], steps[:, None] - 1)
    dt_pad = np.where(np.arange(L)[None, :] < steps[:, None], dt_all[step_idx], 0.0)
    dur = imu.t[starts] - imu.t[ends]
    # Residual noise: both gravity directions, angle random walk and bias error over the
    # rotation.
    sig_rot = np.sqrt(sig_dir[:-1] ** 2 + sig_dir[1:] ** 2 + density**2 * dur
                      + float(np.mean(bg_sd**2)) * dur**2)
    return fit_gyro(gyro_pad, dt_pad, u[:-1], u[1:], sig_rot, bg, prior)


def _sigmas(afit: AccelFit, gfit: GyroFit) -> tuple[Array, Array, Array]:
    """1-sigma of ``M_a`` (zero above the diagonal), ``b_a`` and ``M_g``."""
    a_sig = np.sqrt(np.clip(np.diag(afit.cov), 0.0, None))
    Ma_sig = np.zeros((3, 3))
    for k, (i, j) in enumerate(LOWER):
        Ma_sig[i, j] = a_sig[k]
    Mg_sig = np.sqrt(np.clip(np.diag(gfit.cov), 0.0, None)).reshape(3, 3)
    return Ma_sig, a_sig[6:9], Mg_sig


def _poorly_determined(Ma_sig: Array, ba_sig: Array, Mg_sig: Array, bg_sd: Array,
                       afit: AccelFit, gfit: GyroFit) -> list[str]:
    poor = _poor("accel_matrix", Ma_sig, lower_only=True)
    poor += [f"accel_bias[{i}] (sigma {s:.2g} m/s^2)" for i, s in enumerate(ba_sig)
             if not s <= POOR_SIGMA["accel_bias"]]
    poor += _poor("gyro_matrix", Mg_sig)
    poor += [f"gyro_bias[{i}] (sigma {s:.2g} rad/s)" for i, s in enumerate(bg_sd)
             if not s <= POOR_SIGMA["gyro_bias"]]
    for name, cond in (("accel", afit.condition), ("gyro", gfit.condition)):
        if not cond <= POOR_CONDITION:
            poor.append(f"{name} fit ill-conditioned (condition number {cond:.2g})")
    return poor


def calibrate_multipos(
    imu: ImuSamples,
    *,
    init_static_s: float = 30.0,
    window_s: float = 1.0,
    threshold_multiples: Sequence[float] = tuple(range(2, 11)),
    min_interval_s: float = 0.5,
    gravity: float = 9.81,
    min_orientations: int = 9,
    prior: MultiposPrior | None = None,
    names: Mapping[str, str] | None = None,
) -> MultiposResult:
    """Calibrate accelerometer and gyroscope intrinsics from a multi-position session.

    Args:
        imu: the session: ``init_static_s`` at rest, then static orientations (2-4 s each)
            joined by rotations.
        init_static_s: length of the initial static period (the session must start with at
            least this long at rest; 30-50 s recommended).
        window_s: static-detector window ``t_w`` (1-2 s).
        threshold_multiples: multiples ``k`` of the initial variance magnitude to try.
        min_interval_s: shortest static interval used.
        gravity: local ``|g|`` in m/s^2.
        min_orientations: fewest distinct static orientations accepted.
        prior: optional prior on any of the parameters (see :class:`MultiposPrior`).
        names: how messages spell the options (keyword -> e.g. ``--init-static``); default
            the keywords.

    Returns:
        The intrinsics with 1-sigma, residuals and diagnostics.

    Raises:
        InputError: bad timestamps or options.
        ObservabilityError: no initial static period, log too short, too few or too similar
            static orientations.
        ConvergenceError: a fit failed.
    """
    rate = _check_options(imu, init_static_s, window_s, min_interval_s, gravity,
                          min_orientations, names)
    det = make_detector(imu, rate, init_static_s, window_s, min_interval_s, names)
    choice = _scan(det, imu.accel, threshold_multiples, min_orientations, gravity, prior)
    iv, afit = choice.intervals, choice.fit
    bg, bg_sd, density = _gyro_bias_with_prior(imu.gyro[det.init_mask], rate, prior)
    gfit = _fit_rotations(imu, iv, afit, gravity, bg, bg_sd, density, prior)
    Ma_sig, ba_sig, Mg_sig = _sigmas(afit, gfit)
    return MultiposResult(
        accel_matrix=afit.M, accel_bias=afit.b, gyro_matrix=gfit.M, gyro_bias=bg,
        accel_matrix_sigma=Ma_sig, accel_bias_sigma=ba_sig, gyro_matrix_sigma=Mg_sig,
        gyro_bias_sigma=bg_sd,
        accel_residual_rms=afit.rms, gyro_residual_rms=gfit.rms,
        threshold_multiple=choice.k, n_static_intervals=len(iv),
        n_distinct_orientations=choice.n_distinct,
        static_intervals=np.stack([imu.t[iv[:, 0]], imu.t[iv[:, 1]]], axis=1),
        poorly_determined=_poorly_determined(Ma_sig, ba_sig, Mg_sig, bg_sd, afit, gfit),
        accel_condition=afit.condition, gyro_condition=gfit.condition,
        accel_chi2=afit.chi2, gyro_chi2=gfit.chi2, gravity=float(gravity),
        session_time_ns=int(imu.stamps_ns()[0]),
        prior_source=None if prior is None else prior.source,
        threshold_scan=choice.scan,
    )
