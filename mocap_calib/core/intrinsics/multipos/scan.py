"""Threshold scan of the static detector: one accelerometer fit per multiple ``k`` on interval
sets that can determine it, and the choice among them."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.intrinsics.multipos.detector import Detector, check_timing
from mocap_calib.core.intrinsics.multipos.fit import AccelFit, fit_accel
from mocap_calib.core.intrinsics.multipos.params import DISTINCT_DEG, option, option_value
from mocap_calib.core.intrinsics.multipos.prior import MultiposPrior
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.errors import ConvergenceError, InputError, ObservabilityError

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]


def interval_moments(x: Array, iv: IntArray) -> tuple[Array, Array]:
    """Mean of each interval and the per-axis variance of that mean (white noise)."""
    means = np.empty((len(iv), x.shape[1]))
    var_mean = np.empty((len(iv), x.shape[1]))
    for k, (a, b) in enumerate(iv):
        y = x[a:b + 1]
        means[k] = y.mean(axis=0)
        var_mean[k] = y.var(axis=0, ddof=1) / len(y)
    return means, var_mean


def interval_stats(accel: Array, iv: IntArray) -> tuple[Array, Array]:
    """Mean accel of each interval and the 1-sigma of its norm from the in-interval noise (in
    the units of ``accel``)."""
    means, var_mean = interval_moments(accel, iv)
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


@dataclass(frozen=True)
class Choice:
    """The threshold chosen by the scan and its accelerometer fit."""

    k: float
    intervals: IntArray
    fit: AccelFit
    n_distinct: int
    scan: list[dict[str, Any]]


def check_options(imu: ImuSamples, init_static_s: float, window_s: float,
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


def scan_thresholds(det: Detector, accel: Array, thresholds: Sequence[float],
                    min_orientations: int, gravity: float, prior: MultiposPrior | None
                    ) -> Choice:
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
    return Choice(k_best, iv, afit, n_distinct, scan)


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
