"""``calibrate_multipos``: static detector, threshold scan with the accelerometer fit, gyro bias
(and g-sensitivity) from the static poses, gyroscope fit over the rotations, sigmas and the
poorly-determined list; for raw counts, the starting point from the data and the result in
SI and in imu_tk's form.

The fits run on readings in *start units* (SI input: the readings; raw counts: counts turned
into nominal SI by the starting point); noise and residuals are compared in calibrated units,
with the noise re-expressed through the fitted matrices and the fits repeated once with it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.intrinsics.multipos.detector import (
    Detector,
    check_initial_gyro,
    make_detector,
)
from mocap_calib.core.intrinsics.multipos.fit import AccelFit, GyroFit, fit_accel, fit_gyro
from mocap_calib.core.intrinsics.multipos.gsens import (
    GSensitivityFit,
    fit_g_sensitivity,
    interval_gyro_means,
)
from mocap_calib.core.intrinsics.multipos.params import option
from mocap_calib.core.intrinsics.multipos.prior import MultiposPrior, prior_in_units
from mocap_calib.core.intrinsics.multipos.quality import (
    calibrated_norm_sigma,
    gyro_noise,
    poorly_determined,
    sigmas,
)
from mocap_calib.core.intrinsics.multipos.result import MultiposResult
from mocap_calib.core.intrinsics.multipos.scan import (
    Choice,
    check_options,
    interval_moments,
    scan_thresholds,
)
from mocap_calib.core.intrinsics.multipos.start import gyro_start_scale
from mocap_calib.core.intrinsics.multipos.units import RawConversion, ellipsoid_start, imu_tk_form
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.core.policy import GRAVITY, gap_threshold
from mocap_calib.errors import InputError, ObservabilityError

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

G_MODES = ("auto", "on", "off")


@dataclass(frozen=True)
class _Rotations:
    """The samples of every rotation between consecutive static intervals, padded to one
    length (padding repeats the last sample with zero steps, i.e. identity increments)."""

    idx: IntArray  # (m, L+1) sample indices
    dt: Array  # (m, L) step lengths
    dur: Array  # (m,) durations
    before: IntArray  # (m,) the static interval before each rotation (the next one after)

    @classmethod
    def between(cls, t: Array, iv: IntArray) -> _Rotations:
        """The rotations between consecutive static intervals, but those across an IMU gap
        (the gyro cannot be integrated over it)."""
        gap = np.concatenate([[0], np.cumsum(np.diff(t) > gap_threshold(t))])
        before = np.flatnonzero(gap[iv[1:, 0]] == gap[iv[:-1, 1]])
        if len(before) == 0:
            raise ObservabilityError("every rotation between static poses spans an IMU gap; "
                                     "the gyro cannot be calibrated: re-record")
        starts, ends = iv[before + 1, 0], iv[before, 1]
        steps = starts - ends
        L = int(steps.max())
        idx = ends[:, None] + np.minimum(np.arange(L + 1)[None, :], steps[:, None])
        step_idx = ends[:, None] + np.minimum(np.arange(L)[None, :], steps[:, None] - 1)
        dt = np.where(np.arange(L)[None, :] < steps[:, None], np.diff(t)[step_idx], 0.0)
        return cls(idx, dt, t[starts] - t[ends], before)


@dataclass(frozen=True)
class _Gyro:
    """What the gyro fit needs besides the rotations: the offset subtracted from the readings
    (bias, plus ``G f`` with the g-sensitivity) and the noise."""

    bias: Array
    bias_sd: Array
    G: Array | None

    def offset(self, f: Array) -> Array:
        """``b_g + G f`` for specific forces ``f`` (..., 3)."""
        return self.bias if self.G is None else self.bias + f @ self.G.T


def _accel_start(imu: ImuSamples, det: Detector, thresholds: Sequence[float],
                 gravity: float, nominal: RawConversion | None,
                 names: Mapping[str, str] | None) -> RawConversion:
    """Raw counts: the accelerometer part of the starting point (the nominal one if given,
    else an ellipsoid through the static means of the threshold that finds the most); the
    gyro part is left as the counts until :func:`_gyro_start`."""
    if nominal is not None:
        return RawConversion(nominal.accel_scale, nominal.accel_offset, np.ones(3), np.zeros(3),
                             "start")
    best = max((det.intervals(float(k)) for k in thresholds), key=len)
    means, _ = interval_moments(imu.accel, best) if len(best) else (np.zeros((0, 3)), None)
    found = ellipsoid_start(means, gravity)
    if found is None:
        raise InputError(f"cannot find a starting point for the raw accelerometer counts from "
                         f"the {len(best)} static intervals; pass its nominal scale and offset "
                         f"({option(names, 'accel_scale')}, {option(names, 'accel_offset')})")
    return RawConversion(found[0], found[1], np.ones(3), np.zeros(3), "start")


def _accel_refit(accel: Array, choice: Choice, gravity: float,
                 prior: MultiposPrior | None) -> tuple[AccelFit, Array]:
    """The chosen accelerometer fit repeated with the noise in calibrated units; returns it and
    the calibrated 1-sigma of each interval's norm."""
    means, var_mean = interval_moments(accel, choice.intervals)
    sig = calibrated_norm_sigma(means, var_mean, choice.fit.M, choice.fit.b)
    fit = fit_accel(means, sig, gravity, prior, start=choice.fit)
    if not fit.ok:
        # Cannot happen short of a degenerate session (the weights change by the scale
        # errors only); the scan's fit is then the answer, its noise in start units.
        fit = choice.fit
    return fit, calibrated_norm_sigma(means, var_mean, fit.M, fit.b)


def _gyro_start(imu: ImuSamples, start: RawConversion, rot: _Rotations, u: Array,
                init_mask: NDArray[np.bool_], nominal: RawConversion | None) -> RawConversion:
    """Raw counts: the gyro scale of the starting point (a scan, or the nominal one if that
    explains the rotations better)."""
    bias = imu.gyro[init_mask].mean(axis=0)
    w = imu.gyro[rot.idx] - bias
    cands = () if nominal is None else (float(np.mean(nominal.gyro_scale)),)
    s = gyro_start_scale(w, rot.dt, u[rot.before], u[rot.before + 1], cands)
    if not np.isfinite(s):
        raise InputError("the gyro shows no rotation between the static poses; check the gyro "
                         "columns")
    if nominal is not None and s == cands[0]:
        return replace(start, gyro_scale=nominal.gyro_scale, gyro_offset=nominal.gyro_offset)
    return replace(start, gyro_scale=np.full(3, s), gyro_offset=np.zeros(3))


def _g_sensitivity(imu: ImuSamples, iv: IntArray, afit: AccelFit, mode: str
                   ) -> tuple[GSensitivityFit | None, bool]:
    """``G`` from the static poses and whether the model keeps it (``mode``: auto decides by
    the likelihood-ratio test)."""
    if mode == "off":
        return None, False
    gm, gs = interval_gyro_means(imu.gyro, iv)
    means, _ = interval_moments(imu.accel, iv)
    f = (means - afit.b) @ np.linalg.inv(afit.M).T
    fit = fit_g_sensitivity(gm, gs, f)
    if fit is None:
        return None, False
    return fit, mode == "on" or fit.significant


def _bias(gyro_init: Array, gfit: GSensitivityFit | None, keep: bool,
          prior: MultiposPrior | None) -> _Gyro:
    """Gyro bias: the mean over the initial rest (``w = 0`` there), or with ``G`` the intercept
    of the static poses; combined with a prior if given."""
    if keep and gfit is not None:
        bg, bg_sd, G = gfit.bias, gfit.bias_sigma, gfit.G
    else:
        n = len(gyro_init)
        bg, G = gyro_init.mean(axis=0), None
        sd_white = gyro_init.std(axis=0, ddof=1) / np.sqrt(n)
        # Block means catch correlated noise (random walk, flicker) the white estimate misses.
        blk = n // 10
        blocks = gyro_init[:10 * blk].reshape(10, blk, 3).mean(axis=1)
        bg_sd = np.maximum(sd_white, blocks.std(axis=0, ddof=1) / np.sqrt(10))
    if prior is not None:
        v, s, used = prior.rows("gyro_bias")
        w_d, w_p = 1.0 / bg_sd**2, np.where(used, 1.0 / np.where(used, s, 1.0) ** 2, 0.0)
        bg = (w_d * bg + w_p * np.where(used, v, 0.0)) / (w_d + w_p)
        bg_sd = 1.0 / np.sqrt(w_d + w_p)
    return _Gyro(bg, bg_sd, G)


def _fit_rotations(imu: ImuSamples, rot: _Rotations, u: Array, sig_dir: Array, gyro: _Gyro,
                   afit: AccelFit, init_mask: NDArray[np.bool_], rate: float,
                   prior: MultiposPrior | None) -> GyroFit:
    """Gyro matrix from the rotations, twice: the second time with the gyro noise (angle
    random walk, bias error) in the calibrated units of the first."""
    L_a = np.linalg.inv(afit.M)
    f_rot = (imu.accel[rot.idx] - afit.b) @ L_a.T
    f_init = (imu.accel[init_mask] - afit.b) @ L_a.T
    gyro_pad, offset = imu.gyro[rot.idx], gyro.offset(f_rot)
    fit: GyroFit | None = None
    for _ in range(2):
        M_g = np.eye(3) if fit is None else fit.M
        density, bg_sd = gyro_noise(imu.gyro[init_mask], gyro.offset(f_init), M_g,
                                    gyro.bias_sd, rate)
        # Residual noise: both gravity directions, angle random walk and bias error over the
        # rotation.
        sig_rot = np.sqrt(sig_dir[rot.before] ** 2 + sig_dir[rot.before + 1] ** 2
                          + density**2 * rot.dur
                          + float(np.mean(bg_sd**2)) * rot.dur**2)
        fit = fit_gyro(gyro_pad, rot.dt, u[rot.before], u[rot.before + 1], sig_rot, offset,
                       prior,
                       start=None if fit is None else fit.M)
    assert fit is not None
    return fit


def _prepare(raw: bool, nominal: RawConversion | None,
             prior: MultiposPrior | None) -> None:
    """Checks that the options fit together."""
    if nominal is not None and not raw:
        raise InputError("a nominal scale and offset apply to raw counts only (raw=True)")
    if prior is not None and prior.counts != raw:
        what = "raw counts" if prior.counts else "SI units"
        raise InputError(f"the prior is a calibration of {what} and this one is not; give "
                         "priors calibrated from the same kind of readings")


def _output_units(start: RawConversion, nominal: RawConversion | None, afit: AccelFit,
                  gfit: GyroFit) -> RawConversion:
    """Raw counts: the conversion the result is given for (the nominal one, else imu_tk's
    ``K`` of this calibration with zero offset, so the SI matrices are ``T^-1``)."""
    if nominal is not None:
        return nominal
    K = {}
    for sensor, M in (("accel", afit.M), ("gyro", gfit.M)):
        # Counts form M_r = diag(1 / scale) M (the offset does not enter K).
        _, Kd, _ = imu_tk_form(M / start.scale(sensor)[:, None], np.zeros(3))
        K[sensor] = np.diag(Kd)
    return RawConversion(K["accel"], np.zeros(3), K["gyro"], np.zeros(3), "fitted")


def calibrate_multipos(
    imu: ImuSamples,
    *,
    init_static_s: float = 30.0,
    window_s: float = 1.0,
    threshold_multiples: Sequence[float] = tuple(range(2, 11)),
    min_interval_s: float = 0.5,
    gravity: float = GRAVITY,
    min_orientations: int = 9,
    prior: MultiposPrior | None = None,
    names: Mapping[str, str] | None = None,
    raw: bool = False,
    nominal: RawConversion | None = None,
    g_sensitivity: str = "auto",
) -> MultiposResult:
    """Calibrate accelerometer and gyroscope intrinsics from a multi-position session.

    Args:
        imu: the session: ``init_static_s`` at rest, then static orientations (2-4 s each)
            joined by rotations. In rad/s and m/s^2, or raw counts with ``raw``.
        init_static_s: length of the initial static period (30-50 s recommended).
        window_s: static-detector window ``t_w`` (1-2 s).
        threshold_multiples: multiples ``k`` of the initial variance norm to try (imu_tk's
            meaning, :mod:`.detector`).
        min_interval_s: shortest static interval used.
        gravity: local ``|g|`` in m/s^2.
        min_orientations: fewest distinct static orientations accepted.
        prior: optional prior on any of the parameters (see :class:`MultiposPrior`).
        names: how messages spell the options (keyword -> e.g. ``--init-static``).
        raw: the readings are raw counts in unknown units.
        nominal: with ``raw``, datasheet scales and offsets: the starting point and the
            units the result is given in (default: found from the data; result in imu_tk's
            ``K`` units).
        g_sensitivity: ``auto`` (keep ``G`` if the likelihood-ratio test says so), ``on``,
            ``off``.

    Returns:
        The intrinsics with 1-sigma, residuals and diagnostics.

    Raises:
        InputError: bad timestamps or options.
        ObservabilityError: no initial static period, log too short, too few or too similar
            static orientations.
        ConvergenceError: a fit failed.
    """
    if g_sensitivity not in G_MODES:
        raise InputError(f"{option(names, 'g_sensitivity')} {g_sensitivity}: use auto, on or "
                         "off")
    _prepare(raw, nominal, prior)
    rate = check_options(imu, init_static_s, window_s, min_interval_s, gravity,
                         min_orientations, names)
    det = make_detector(imu, rate, init_static_s, window_s, min_interval_s, names,
                        check_gyro=not raw)
    start = (_accel_start(imu, det, threshold_multiples, gravity, nominal, names) if raw
             else RawConversion.identity())
    imu_s = start.apply(imu) if raw else imu
    prior_s = prior_in_units(prior, start) if prior is not None and raw else prior
    choice = scan_thresholds(det, imu_s.accel, threshold_multiples, min_orientations,
                             gravity, prior_s)
    afit, sig_int = _accel_refit(imu_s.accel, choice, gravity, prior_s)
    iv = choice.intervals
    means, _ = interval_moments(imu_s.accel, iv)
    h = (means - afit.b) @ np.linalg.inv(afit.M).T
    u = h / np.linalg.norm(h, axis=1, keepdims=True)
    rot = _Rotations.between(imu.t, iv)
    if raw:
        start = _gyro_start(imu_s, start, rot, u, det.init_mask, nominal)
        imu_s = start.apply(imu)
        prior_s = prior_in_units(prior, start) if prior is not None else None
        check_initial_gyro(imu_s.gyro[det.init_mask], rate, init_static_s, names)
    return _finish(imu, imu_s, det, choice, afit, sig_int / gravity, u, rot, rate, gravity,
                   prior_s, g_sensitivity, start if raw else None, nominal, prior)


def _finish(imu: ImuSamples, imu_s: ImuSamples, det: Detector, choice: Choice, afit: AccelFit,
            sig_dir: Array, u: Array, rot: _Rotations, rate: float, gravity: float,
            prior_s: MultiposPrior | None, g_mode: str, start: RawConversion | None,
            nominal: RawConversion | None, prior: MultiposPrior | None) -> MultiposResult:
    """Gyro bias and g-sensitivity, gyro fit, sigmas, and the result in its output units."""
    iv = choice.intervals
    gs, keep = _g_sensitivity(imu_s, iv, afit, g_mode)
    gyro = _bias(imu_s.gyro[det.init_mask], gs, keep, prior_s)
    gfit = _fit_rotations(imu_s, rot, u, sig_dir, gyro, afit, det.init_mask, rate, prior_s)
    test = None
    if gs is not None:
        # The other model, for the report: how much G changes the gyro integration.
        other = _bias(imu_s.gyro[det.init_mask], gs, not keep, prior_s)
        alt = _fit_rotations(imu_s, rot, u, sig_dir, other, afit, det.init_mask, rate,
                             prior_s)
        with_g, without_g = (gfit, alt) if keep else (alt, gfit)
        test = {**gs.test_dict(), "kept": bool(keep), "gyro_rms_rad_with_g": with_g.rms,
                "gyro_rms_rad_without_g": without_g.rms, "gyro_chi2_with_g": with_g.chi2,
                "gyro_chi2_without_g": without_g.chi2}
    Ma_sig, ba_sig, Mg_sig = sigmas(afit, gfit)
    res = MultiposResult(
        accel_matrix=afit.M, accel_bias=afit.b, gyro_matrix=gfit.M, gyro_bias=gyro.bias,
        accel_matrix_sigma=Ma_sig, accel_bias_sigma=ba_sig, gyro_matrix_sigma=Mg_sig,
        gyro_bias_sigma=gyro.bias_sd,
        accel_residual_rms=afit.rms, gyro_residual_rms=gfit.rms,
        threshold_multiple=choice.k, n_static_intervals=len(iv),
        n_distinct_orientations=choice.n_distinct,
        static_intervals=np.stack([imu.t[iv[:, 0]], imu.t[iv[:, 1]]], axis=1),
        poorly_determined=poorly_determined(afit, gfit, Ma_sig, ba_sig, Mg_sig, gyro.bias_sd),
        accel_condition=afit.condition, gyro_condition=gfit.condition,
        accel_chi2=afit.chi2, gyro_chi2=gfit.chi2, gravity=float(gravity),
        session_time_ns=int(imu.stamps_ns()[0]),
        prior_source=None if prior is None else prior.source,
        threshold_scan=choice.scan,
        g_sensitivity=gs.G if keep and gs is not None else None,
        g_sensitivity_sigma=gs.G_sigma if keep and gs is not None else None,
        g_sensitivity_test=test, raw_input=start)
    if start is None:
        return res
    return res.in_units(_output_units(start, nominal, afit, gfit))
