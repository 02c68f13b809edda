"""Multi-position IMU calibration without external equipment (Tedaldi, Pretto, Menegatti,
"A robust and easy to implement method for IMU calibration without external equipments",
ICRA 2014; the imu_tk implementation).

The session is an initial static period (``T_init``), then 36-50 static orientations of a few
seconds each joined by short rotations. The calibration runs in three steps:

1. *Static detector*: the magnitude ``|var_w(a)|^2`` of the per-axis accel variance over a
   centred window ``t_w`` is compared with ``k |var_init(a)|^2``, the same magnitude over the
   initial static period. ``k`` is scanned (2..10, as imu_tk) and chosen by the accelerometer
   calibration residual, so no threshold has to be tuned.
2. *Accelerometer*: 9 parameters (lower-triangular ``M_a``: 3 scales, 3 misalignments; bias
   ``b_a``) minimise ``sum_i (g^2 - |h_i|^2)^2`` with ``h_i = M_a^-1 (mean_i(a_m) - b_a)`` over
   the static intervals, by Levenberg-Marquardt.
3. *Gyroscope*: ``b_g`` is the mean gyro over the initial static period; ``M_g`` (9 entries)
   makes the RK4 quaternion integration of ``M_g^-1 (w_m - b_g)`` between consecutive static
   intervals carry the calibrated gravity direction of one interval onto that of the next.

The model is the measurement form of ``docs/conventions.md``: ``a_m = M_a f + b_a``,
``w_m = M_g w + b_g``. The IMU frame is the accelerometer's orthogonalised frame, hence ``M_a``
lower-triangular.

Two deliberate departures from imu_tk, both small: residuals are whitened by the noise of each
interval mean (measured inside the interval), and ``k`` is chosen by the *reduced* chi-square
(imu_tk uses the total cost, which favours thresholds that find fewer intervals); among
thresholds whose reduced chi-square is statistically indistinguishable from the best, the one
that finds the most intervals wins.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from mocap_calib.core.model import so3
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.errors import ConvergenceError, InputError, ObservabilityError

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Parameters of the multi-position model, with their shapes.
PARAMETERS: dict[str, tuple[int, ...]] = {
    "accel_matrix": (3, 3),
    "accel_bias": (3,),
    "gyro_matrix": (3, 3),
    "gyro_bias": (3,),
}

#: Free entries of the lower-triangular ``M_a``.
_LOWER = [(0, 0), (1, 0), (1, 1), (2, 0), (2, 1), (2, 2)]

#: 1-sigma above which a parameter is reported as poorly determined.
POOR_SIGMA: dict[str, float] = {
    "scale": 1e-3,  # diagonal of M_a, M_g (relative)
    "misalignment": float(np.radians(0.05)),  # off-diagonal of M_a, M_g (rad)
    "accel_bias": 5e-3,  # m/s^2
    "gyro_bias": 1e-4,  # rad/s
}

#: Condition number (of the column-normalised normal matrix) above which a fit is flagged.
POOR_CONDITION = 1e8

#: Two static intervals count as distinct orientations if their gravity directions differ by
#: more than this angle.
DISTINCT_DEG = 10.0

_IDENTITY_Q = np.array([1.0, 0.0, 0.0, 0.0])


# --------------------------------------------------------------------------------------------
# Quaternion integration (shared with attitude_drift)
# --------------------------------------------------------------------------------------------

def _pure(v: Array) -> Array:
    return np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], axis=-1)


def rk4_increments(omega: Array, dt: Array) -> Array:
    """Quaternion increments ``p_k`` of one RK4 step each, ``q_{k+1} = q_k * p_k``.

    RK4 on ``q' = 1/2 q * (0, w)`` with the body rate linearly interpolated between samples
    (``w`` at ``t_k``, the midpoint average, ``w`` at ``t_{k+1}``, as imu_tk). The ODE is linear
    and acts by right multiplication, so every RK4 stage is ``q_k`` times a quaternion that does
    not depend on ``q_k``: the increments of all steps are computed at once, and the attitude is
    their ordered product (:func:`quat_product`, :func:`quat_cumprod`).

    Args:
        omega: (..., n, 3) body rates in rad/s at the sample times.
        dt: (..., n-1) step lengths in s.

    Returns:
        (..., n-1, 4) increments ``[w, x, y, z]`` (unit norm up to O(dt^5)).
    """
    w1 = omega[..., :-1, :]
    w3 = omega[..., 1:, :]
    w2 = 0.5 * (w1 + w3)
    h = np.asarray(dt, dtype=float)[..., None]
    one = np.zeros(w1.shape[:-1] + (4,))
    one[..., 0] = 1.0
    a1 = 0.5 * _pure(w1)
    a2 = 0.5 * so3.quat_multiply(one + 0.5 * h * a1, _pure(w2))
    a3 = 0.5 * so3.quat_multiply(one + 0.5 * h * a2, _pure(w2))
    a4 = 0.5 * so3.quat_multiply(one + h * a3, _pure(w3))
    return one + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)


def quat_product(p: Array) -> Array:
    """Ordered product ``p_0 * p_1 * ... * p_{n-1}`` along axis -2 (pairwise tree, normalised).

    Args:
        p: (..., n, 4) quaternions; identity entries can pad sequences of unequal length.

    Returns:
        (..., 4) unit quaternions.
    """
    p = np.asarray(p, dtype=float)
    if p.shape[-2] == 0:
        return np.broadcast_to(_IDENTITY_Q, p.shape[:-2] + (4,)).copy()
    while p.shape[-2] > 1:
        if p.shape[-2] % 2:
            pad = np.broadcast_to(_IDENTITY_Q, p.shape[:-2] + (1, 4))
            p = np.concatenate([p, pad], axis=-2)
        p = so3.quat_multiply(p[..., 0::2, :], p[..., 1::2, :])
    q = p[..., 0, :]
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_cumprod(p: Array) -> Array:
    """Inclusive ordered prefix products ``p_0 * ... * p_i`` (Hillis-Steele scan, normalised).

    Args:
        p: (n, 4) quaternions.

    Returns:
        (n, 4) unit quaternions.
    """
    out = np.array(p, dtype=float, copy=True)
    d = 1
    while d < len(out):
        out[d:] = so3.quat_multiply(out[:-d], out[d:])
        d *= 2
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


# --------------------------------------------------------------------------------------------
# Static detector
# --------------------------------------------------------------------------------------------

def _window_samples(window_s: float, rate_hz: float) -> int:
    """Odd number of samples in a window of ``window_s`` (at least 11, as imu_tk)."""
    w = max(11, int(round(window_s * rate_hz)))
    return w if w % 2 else w + 1


def variance_magnitude(accel: Array, win: int) -> Array:
    """``|var_w(a)|^2``: squared norm of the per-axis variance over a centred window.

    Args:
        accel: (N, 3) accel samples.
        win: odd window length in samples.

    Returns:
        (N,) magnitudes; NaN where the window does not fit (the first and last ``win // 2``).
    """
    n = len(accel)
    out = np.full(n, np.nan)
    if n < win:
        return out
    # Centre the data first so the cumulative sums do not lose the variance to cancellation.
    x = accel - np.median(accel, axis=0)
    c1 = np.concatenate([np.zeros((1, 3)), np.cumsum(x, axis=0)])
    c2 = np.concatenate([np.zeros((1, 3)), np.cumsum(x * x, axis=0)])
    s1 = c1[win:] - c1[:-win]
    s2 = c2[win:] - c2[:-win]
    var = np.clip((s2 - s1 * s1 / win) / (win - 1), 0.0, None)
    h = win // 2
    out[h:n - h] = np.sum(var * var, axis=1)
    return out


def _runs(mask: NDArray[np.bool_], min_len: int) -> IntArray:
    """[start, end] (inclusive) of the runs of True at least ``min_len`` long."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1) - 1
    keep = ends - starts + 1 >= min_len
    return np.stack([starts[keep], ends[keep]], axis=1).astype(np.int64)


@dataclass(frozen=True)
class _Detector:
    """What the static detector needs, computed once for every threshold multiple."""

    magnitude: Array
    init_mask: NDArray[np.bool_]
    init_magnitude: float
    min_len: int

    def intervals(self, k: float) -> IntArray:
        with np.errstate(invalid="ignore"):
            static = self.magnitude < k * self.init_magnitude
        return _runs(static, self.min_len)


def _check_timing(imu: ImuSamples) -> float:
    if len(imu) < 100:
        raise InputError(f"{imu.source}: only {len(imu)} IMU samples; a multi-position session "
                         "has thousands (several minutes at 100-1000 Hz)")
    dt = np.diff(imu.t)
    if np.any(dt <= 0):
        row = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise InputError(f"{imu.source}: timestamps are not strictly increasing at sample "
                         f"{row}; sort the log by time and drop duplicate stamps")
    rate = imu.rate_hz
    if not 10.0 <= rate <= 10000.0:
        raise InputError(f"{imu.source}: sample rate {rate:.3g} Hz is outside 10-10000 Hz; "
                         "check the timestamp unit (nanoseconds expected)")
    return rate


def _make_detector(imu: ImuSamples, rate: float, init_static_s: float, window_s: float,
                   min_interval_s: float) -> _Detector:
    win = _window_samples(window_s, rate)
    init_mask = imu.t - imu.t[0] <= init_static_s
    if init_mask.sum() < 2 * win:
        raise InputError(f"init_static_s={init_static_s:g} s is shorter than two detector "
                         f"windows ({2 * win / rate:.1f} s); use 30-50 s")
    mag = variance_magnitude(imu.accel, win)
    var_init = imu.accel[init_mask].var(axis=0, ddof=1)
    init_mag = float(np.sum(var_init**2))
    _check_initial_static(imu, init_mask, mag, init_mag, init_static_s, rate)
    # Floor for quantised, nearly noise-free data: a zero threshold would find nothing static.
    init_mag = max(init_mag, 1e-16)
    min_len = max(win // 2, int(round(min_interval_s * rate)))
    return _Detector(mag, init_mask, init_mag, min_len)


def _check_initial_static(imu: ImuSamples, init_mask: NDArray[np.bool_], mag: Array,
                          init_mag: float, init_static_s: float, rate: float) -> None:
    """Raise if the initial period is not static: its threshold would then mean nothing."""
    inner = mag[init_mask]
    inner = inner[np.isfinite(inner)]
    fix = (f"start the recording with the IMU resting still for {init_static_s:.0f}-50 s "
           "(or pass a shorter init_static_s)")
    # Over a static period the windowed variance is the whole period's variance (noise); a
    # motion or a tilt inside it makes the whole-period variance much larger.
    if init_mag > 25.0 * float(np.median(inner)):
        raise ObservabilityError(f"no initial static period: the accelerometer varies within "
                                 f"the first {init_static_s:.0f} s; {fix}")
    # A rotation that keeps the gravity direction (about the vertical) shows only on the gyro.
    g = imu.gyro[init_mask]
    blk = max(1, int(round(rate)))
    nb = len(g) // blk
    means = g[:nb * blk].reshape(nb, blk, 3).mean(axis=1)
    spread = float(np.max(np.abs(means - np.median(means, axis=0))))
    if spread > 0.05:
        raise ObservabilityError(f"no initial static period: the gyro shows rotation "
                                 f"({np.degrees(spread):.1f} deg/s) within the first "
                                 f"{init_static_s:.0f} s; {fix}")


def detect_static_intervals(imu: ImuSamples, threshold_multiple: float, *,
                            init_static_s: float = 30.0, window_s: float = 1.0,
                            min_interval_s: float = 0.5) -> IntArray:
    """Static intervals of a multi-position session for one threshold multiple ``k``.

    Args:
        imu: the session.
        threshold_multiple: ``k`` in ``|var_w(a)|^2 < k |var_init(a)|^2``.
        init_static_s: length of the initial static period.
        window_s: length of the centred variance window ``t_w``.
        min_interval_s: shortest interval kept.

    Returns:
        (n, 2) sample indices ``[start, end]`` (inclusive) of the static intervals.
    """
    rate = _check_timing(imu)
    return _make_detector(imu, rate, init_static_s, window_s, min_interval_s).intervals(
        threshold_multiple)


# --------------------------------------------------------------------------------------------
# Priors
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class MultiposPrior:
    """Gaussian prior on multi-position parameters, entered as weighted residual rows.

    Attributes:
        values: parameter name (a key of :data:`PARAMETERS`) -> value array of its shape.
        sigmas: same keys -> 1-sigma array of the same shape; entries that are not finite
            and positive (and the structural zeros above the diagonal of ``accel_matrix``)
            carry no prior.
        source: what the prior came from, for reports.
    """

    values: Mapping[str, Array]
    sigmas: Mapping[str, Array]
    source: str = "prior"

    def __post_init__(self) -> None:
        for name in self.values:
            if name not in PARAMETERS:
                raise InputError(f"prior: unknown parameter '{name}'; use "
                                 f"{', '.join(PARAMETERS)}")
            if name not in self.sigmas:
                raise InputError(f"prior: '{name}' has a value but no sigma; give both")
            shape = PARAMETERS[name]
            v = np.asarray(self.values[name], dtype=float)
            s = np.asarray(self.sigmas[name], dtype=float)
            if v.shape != shape or s.shape != shape:
                raise InputError(f"prior: '{name}' must have shape {shape}, got value "
                                 f"{v.shape} and sigma {s.shape}")

    def rows(self, name: str) -> tuple[Array, Array, NDArray[np.bool_]]:
        """(value, sigma, used) of one parameter, flattened; ``used`` false without a prior."""
        shape = PARAMETERS[name]
        if name not in self.values:
            z = np.zeros(int(np.prod(shape)))
            return z, z + np.inf, np.zeros(len(z), dtype=bool)
        v = np.asarray(self.values[name], dtype=float).ravel()
        s = np.asarray(self.sigmas[name], dtype=float).ravel()
        with np.errstate(invalid="ignore"):
            used = np.isfinite(v) & np.isfinite(s) & (s > 0)
        return v, s, used

    @classmethod
    def from_result(cls, result: MultiposResult | Mapping[str, Any],
                    names: Sequence[str] = tuple(PARAMETERS),
                    sigma_scale: float = 1.0) -> MultiposPrior:
        """Prior from one earlier calibration: its values and (scaled) sigmas.

        Args:
            result: a :class:`MultiposResult` or its ``to_dict()`` (e.g. read from YAML).
            names: which parameters to constrain (e.g. leave out the biases, which change
                from one power-up to the next more than their sigma says).
            sigma_scale: multiply the sigmas by this (> 1 to allow for change since then).
        """
        d = result.to_dict() if isinstance(result, MultiposResult) else result
        return cls.from_history([d], names=names, sigma_scale=sigma_scale)

    @classmethod
    def from_history(cls, results: Sequence[MultiposResult | Mapping[str, Any]],
                     times_s: Sequence[float] | None = None, at_time_s: float | None = None,
                     names: Sequence[str] = tuple(PARAMETERS),
                     sigma_scale: float = 1.0) -> MultiposPrior:
        """Prior from one or more earlier calibrations, extrapolating a first-order trend.

        With one result the prior is its values and sigmas. With two or more at distinct
        times, every entry gets a weighted straight-line fit against time, extrapolated to
        ``at_time_s``; its sigma is the prediction's standard error (scaled up by the fit's
        reduced chi-square when that exceeds 1), so the further the extrapolation, the wider.

        Args:
            results: earlier results (:class:`MultiposResult` or their ``to_dict()``).
            times_s: time of each result in s (any common origin); default: each result's
                ``diagnostics.session_time_ns``.
            at_time_s: time to extrapolate to (same origin); required with two or more.
            names: which parameters to constrain.
            sigma_scale: multiply the final sigmas by this.
        """
        dicts = [r.to_dict() if isinstance(r, MultiposResult) else r for r in results]
        if not dicts:
            raise InputError("prior: give at least one earlier result")
        for name in names:
            if name not in PARAMETERS:
                raise InputError(f"prior: unknown parameter '{name}'; use "
                                 f"{', '.join(PARAMETERS)}")
        if times_s is None and len(dicts) > 1:
            try:
                times_s = [float(d["diagnostics"]["session_time_ns"]) * 1e-9 for d in dicts]
            except (KeyError, TypeError):
                raise InputError("prior: earlier results have no session time; pass times_s "
                                 "with one time per result") from None
        values: dict[str, Array] = {}
        sigmas: dict[str, Array] = {}
        for name in names:
            shape = PARAMETERS[name]
            try:
                y = np.array([np.asarray(d[name], dtype=float) for d in dicts])
                s = np.array([np.asarray(d["sigma"][name], dtype=float) for d in dicts])
            except (KeyError, TypeError, ValueError):
                raise InputError(f"prior: an earlier result lacks '{name}' or its sigma "
                                 f"('sigma: {{{name}: ...}}')") from None
            if y.shape[1:] != shape or s.shape[1:] != shape:
                raise InputError(f"prior: '{name}' must have shape {shape}")
            if len(dicts) == 1:
                values[name], sigmas[name] = y[0], s[0] * sigma_scale
                continue
            if at_time_s is None:
                raise InputError("prior: with two or more earlier results give at_time_s, the "
                                 "time to extrapolate the trend to")
            v, sd = _trend_extrapolate(np.asarray(times_s, dtype=float), y.reshape(len(y), -1),
                                       s.reshape(len(s), -1), float(at_time_s))
            values[name], sigmas[name] = v.reshape(shape), sd.reshape(shape) * sigma_scale
        source = "earlier result" if len(dicts) == 1 else f"trend of {len(dicts)} results"
        return cls(values, sigmas, source)


def _trend_extrapolate(t: Array, y: Array, s: Array, t_now: float) -> tuple[Array, Array]:
    """Weighted first-order fit per column of ``y`` (rows: results), predicted at ``t_now``."""
    out_v = np.zeros(y.shape[1])
    out_s = np.full(y.shape[1], np.inf)
    for c in range(y.shape[1]):
        ok = np.isfinite(y[:, c]) & np.isfinite(s[:, c]) & (s[:, c] > 0)
        if not ok.any():
            continue
        tc, yc, sc = t[ok], y[ok, c], s[ok, c]
        w = 1.0 / sc**2
        if len(tc) == 1 or np.ptp(tc) == 0:
            # No time spread: the best one can do is the weighted mean.
            out_v[c] = np.sum(w * yc) / np.sum(w)
            out_s[c] = 1.0 / np.sqrt(np.sum(w))
            continue
        t_ref = float(np.sum(w * tc) / np.sum(w))
        A = np.stack([np.ones_like(tc), tc - t_ref], axis=1)
        N = A.T @ (A * w[:, None])
        cov = np.linalg.inv(N)
        coef = cov @ (A.T @ (w * yc))
        dof = len(tc) - 2
        if dof > 0:
            chi2 = float(np.sum(w * (yc - A @ coef) ** 2)) / dof
            cov = cov * max(1.0, chi2)
        a = np.array([1.0, t_now - t_ref])
        out_v[c] = float(a @ coef)
        out_s[c] = float(np.sqrt(a @ cov @ a))
    return out_v, out_s


# --------------------------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class MultiposResult:
    """Intrinsics from a multi-position session, in the measurement model's form.

    Attributes:
        accel_matrix: ``M_a`` (3x3, lower-triangular) in ``a_m = M_a f + b_a``.
        accel_bias: ``b_a`` in m/s^2.
        gyro_matrix: ``M_g`` (3x3) in ``w_m = M_g w + b_g``.
        gyro_bias: ``b_g`` in rad/s (mean gyro over the initial static period).
        accel_matrix_sigma: 1-sigma of ``M_a`` (0 above the diagonal: not a parameter).
        accel_bias_sigma: 1-sigma of ``b_a``.
        gyro_matrix_sigma: 1-sigma of ``M_g``.
        gyro_bias_sigma: 1-sigma of ``b_g``.
        accel_residual_rms: RMS of ``|h_i| - g`` over the static intervals, m/s^2.
        gyro_residual_rms: RMS over the rotations of the gravity-direction error, rad.
        threshold_multiple: the chosen static-detector multiple ``k``.
        n_static_intervals: static intervals used (the initial period included).
        n_distinct_orientations: of those, gravity directions more than 10 deg apart.
        static_intervals: (n, 2) start and end time (s, IMU clock) of each interval.
        poorly_determined: parameters whose sigma is large (see :data:`POOR_SIGMA`), or
            ``"<sensor> fit ill-conditioned ..."``.
        accel_condition: condition number of the accel fit's normal matrix (columns
            normalised).
        gyro_condition: same for the gyro fit.
        accel_chi2: reduced chi-square of the accel fit (1 when the residuals are at the
            noise level of the interval means).
        gyro_chi2: reduced chi-square of the gyro fit.
        gravity: ``|g|`` assumed, m/s^2.
        session_time_ns: stamp of the session's first sample (for trends over sessions).
        prior_source: what the prior came from, or None without one.
        threshold_scan: per tried ``k``: ``{k, n_intervals, chi2}`` (chi2 None if unusable).
    """

    accel_matrix: Array
    accel_bias: Array
    gyro_matrix: Array
    gyro_bias: Array
    accel_matrix_sigma: Array
    accel_bias_sigma: Array
    gyro_matrix_sigma: Array
    gyro_bias_sigma: Array
    accel_residual_rms: float
    gyro_residual_rms: float
    threshold_multiple: float
    n_static_intervals: int
    n_distinct_orientations: int
    static_intervals: Array
    poorly_determined: list[str]
    accel_condition: float
    gyro_condition: float
    accel_chi2: float
    gyro_chi2: float
    gravity: float
    session_time_ns: int
    prior_source: str | None = None
    threshold_scan: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """The intrinsics keys of ``docs/conventions.md`` plus ``sigma``, ``residuals`` and
        ``diagnostics`` (plain Python types, ready for YAML)."""
        return {
            "accel_matrix": self.accel_matrix.tolist(),
            "accel_bias": self.accel_bias.tolist(),
            "gyro_matrix": self.gyro_matrix.tolist(),
            "gyro_bias": self.gyro_bias.tolist(),
            "sigma": {
                "accel_matrix": self.accel_matrix_sigma.tolist(),
                "accel_bias": self.accel_bias_sigma.tolist(),
                "gyro_matrix": self.gyro_matrix_sigma.tolist(),
                "gyro_bias": self.gyro_bias_sigma.tolist(),
            },
            "residuals": {
                "accel_rms_mps2": float(self.accel_residual_rms),
                "gyro_rms_rad": float(self.gyro_residual_rms),
                "accel_chi2": float(self.accel_chi2),
                "gyro_chi2": float(self.gyro_chi2),
            },
            "diagnostics": {
                "threshold_multiple": float(self.threshold_multiple),
                "n_static_intervals": int(self.n_static_intervals),
                "n_distinct_orientations": int(self.n_distinct_orientations),
                "static_intervals_s": self.static_intervals.tolist(),
                "poorly_determined": list(self.poorly_determined),
                "accel_condition_number": float(self.accel_condition),
                "gyro_condition_number": float(self.gyro_condition),
                "gravity_magnitude": float(self.gravity),
                "session_time_ns": int(self.session_time_ns),
                "prior": self.prior_source,
                "threshold_scan": list(self.threshold_scan),
            },
        }


# --------------------------------------------------------------------------------------------
# Accelerometer fit
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _AccelFit:
    M: Array
    b: Array
    cov: Array  # (9, 9) of [M lower entries (_LOWER order), b]
    chi2: float  # reduced
    dof: int
    rms: float
    condition: float
    ok: bool


def _accel_unpack(p: Array) -> tuple[Array, Array]:
    M = np.zeros((3, 3))
    for k, (i, j) in enumerate(_LOWER):
        M[i, j] = p[k]
    return M, p[6:9]


def _accel_model(p: Array, means: Array, sig: Array, g: float) -> tuple[Array, Array]:
    """Whitened residuals ``(g^2 - |h|^2) / (2 g sigma)`` and their Jacobian."""
    M, b = _accel_unpack(p)
    L = np.linalg.inv(M)
    h = (means - b) @ L.T
    r = (g * g - np.sum(h * h, axis=1)) / (2.0 * g * sig)
    v = h @ L  # v_k = h^T L[:, k]
    J = np.zeros((len(means), 9))
    for k, (i, j) in enumerate(_LOWER):
        J[:, k] = v[:, i] * h[:, j]
    J[:, 6:9] = v
    J /= (g * sig)[:, None]
    return r, J


def _prior_block(prior: MultiposPrior | None, name: str,
                 entries: Sequence[int]) -> tuple[Array, Array, Array]:
    """(indices into this fit's parameter vector, values, sigmas) of the used prior rows."""
    if prior is None:
        return np.zeros(0, dtype=int), np.zeros(0), np.zeros(0)
    v, s, used = prior.rows(name)
    idx, vals, sigs = [], [], []
    for k, flat in enumerate(entries):
        if used[flat]:
            idx.append(k)
            vals.append(v[flat])
            sigs.append(s[flat])
    return np.asarray(idx, dtype=int), np.asarray(vals), np.asarray(sigs)


def _accel_prior(prior: MultiposPrior | None) -> tuple[Array, Array, Array]:
    im, vm, sm = _prior_block(prior, "accel_matrix", [3 * i + j for i, j in _LOWER])
    ib, vb, sb = _prior_block(prior, "accel_bias", [0, 1, 2])
    return np.concatenate([im, ib + 6]), np.concatenate([vm, vb]), np.concatenate([sm, sb])


def _covariance(J: Array, chi2_red: float) -> tuple[Array, float]:
    """``(J^T J)^-1`` scaled by ``max(1, chi2_red)`` and the condition number of ``J^T J``
    with normalised columns (so units do not inflate it)."""
    JtJ = J.T @ J
    d = np.sqrt(np.clip(np.diag(JtJ), 1e-300, None))
    Jn = JtJ / np.outer(d, d)
    cond = float(np.linalg.cond(Jn))
    cov = np.linalg.pinv(Jn, rcond=1e-12) / np.outer(d, d)
    # The residuals are whitened by the measured noise: scale up (never down) by the residual
    # variance so that unmodelled errors widen the sigmas.
    return cov * max(1.0, chi2_red), cond


def _fit_accel(means: Array, sig: Array, g: float, prior: MultiposPrior | None) -> _AccelFit:
    pi, pv, ps = _accel_prior(prior)
    p0 = np.array([1.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    # Start from the prior where there is one: the problem is then closer to linear.
    p0[pi] = pv

    def fun(p: Array) -> Array:
        r, _ = _accel_model(p, means, sig, g)
        return np.concatenate([r, (p[pi] - pv) / ps])

    def jac(p: Array) -> Array:
        _, J = _accel_model(p, means, sig, g)
        Jp = np.zeros((len(pi), 9))
        Jp[np.arange(len(pi)), pi] = 1.0 / ps
        return np.vstack([J, Jp])

    m = len(means) + len(pi)
    res = least_squares(fun, p0, jac=jac, method="lm" if m >= 9 else "trf",
                        xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200)
    M, b = _accel_unpack(res.x)
    dof = m - 9
    chi2 = float(np.sum(res.fun**2)) / dof if dof > 0 else float("nan")
    cov, cond = _covariance(jac(res.x), chi2 if dof > 0 else 1.0)
    h = (means - b) @ np.linalg.inv(M).T
    rms = float(np.sqrt(np.mean((np.linalg.norm(h, axis=1) - g) ** 2)))
    ok = bool(res.success) and np.all(np.isfinite(res.x)) and np.linalg.det(M) > 0.5
    return _AccelFit(M, b, cov, chi2, dof, rms, cond, ok)


# --------------------------------------------------------------------------------------------
# Gyroscope fit
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _GyroFit:
    M: Array
    cov: Array
    chi2: float
    rms: float
    condition: float


def _fit_gyro(gyro_pad: Array, dt_pad: Array, u_start: Array, u_end: Array, sig: Array,
              bias: Array, prior: MultiposPrior | None) -> _GyroFit:
    """Fit ``M_g`` so that integrated rotations carry each start gravity direction to the end.

    Args:
        gyro_pad: (m, L+1, 3) raw gyro of each rotation, padded by repeating the last sample.
        dt_pad: (m, L) step lengths, 0 in the padding (so padded steps are the identity).
        u_start: (m, 3) calibrated gravity direction of the interval before each rotation.
        u_end: (m, 3) same for the interval after.
        sig: (m,) 1-sigma of each residual component (rad).
        bias: gyro bias (fixed).
        prior: optional prior on ``gyro_matrix``.
    """
    pi, pv, ps = _prior_block(prior, "gyro_matrix", list(range(9)))
    x0 = np.eye(3).ravel()
    x0[pi] = pv
    raw = gyro_pad - bias

    def predicted(x: Array) -> Array:
        C = np.linalg.inv(x.reshape(3, 3))
        q = quat_product(rk4_increments(raw @ C.T, dt_pad))
        R = so3.quat_to_rotmat(q)
        # R_WI(end) = R_WI(start) dR, so the body gravity direction moves as dR^T u.
        return np.einsum("mji,mj->mi", R, u_start)

    def fun(x: Array) -> Array:
        r = ((predicted(x) - u_end) / sig[:, None]).ravel()
        return np.concatenate([r, (x[pi] - pv) / ps])

    res = least_squares(fun, x0, method="lm", x_scale=1.0, xtol=1e-12, ftol=1e-12, gtol=1e-12,
                        diff_step=1e-7, max_nfev=400)
    x = res.x
    if not res.success or not np.all(np.isfinite(x)):
        raise ConvergenceError("multipos: the gyroscope fit did not converge; check that the "
                               "rotations between static orientations are in the log without "
                               "gaps and below the gyro's range")
    # Central differences at the optimum for the covariance (LM's returned Jacobian is the
    # forward-difference one of its last step).
    eps = 1e-6
    J = np.empty((len(res.fun), 9))
    for k in range(9):
        d = np.zeros(9)
        d[k] = eps
        J[:, k] = (fun(x + d) - fun(x - d)) / (2 * eps)
    # Each rotation gives 3 residual components but only 2 independent ones (unit vectors).
    n_data = 3 * len(u_start)
    dof = 2 * len(u_start) + len(pi) - 9
    rss = 2.0 / 3.0 * float(np.sum(res.fun[:n_data] ** 2)) + float(np.sum(res.fun[n_data:] ** 2))
    chi2 = rss / dof if dof > 0 else float("nan")
    cov, cond = _covariance(J, chi2 if dof > 0 else 1.0)
    err = np.linalg.norm(predicted(x) - u_end, axis=1)
    return _GyroFit(x.reshape(3, 3), cov, chi2, float(np.sqrt(np.mean(err**2))), cond)


# --------------------------------------------------------------------------------------------
# Calibration
# --------------------------------------------------------------------------------------------

def _interval_stats(accel: Array, iv: IntArray) -> tuple[Array, Array]:
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

    Returns:
        The intrinsics with 1-sigma, residuals and diagnostics.

    Raises:
        InputError: bad timestamps or options.
        ObservabilityError: no initial static period, log too short, too few or too similar
            static orientations.
        ConvergenceError: a fit failed.
    """
    if not 5.0 < gravity < 15.0:
        raise InputError(f"gravity={gravity}: give |g| in m/s^2, e.g. 9.81")
    if not init_static_s > 0 or not window_s > 0 or not min_interval_s > 0:
        raise InputError("init_static_s, window_s and min_interval_s must be positive")
    if min_orientations < 3:
        raise InputError(f"min_orientations={min_orientations}: must be at least 3")
    rate = _check_timing(imu)
    need = init_static_s + min_orientations * (min_interval_s + window_s + 1.0)
    if imu.duration < need:
        raise ObservabilityError(
            f"{imu.source}: log is {imu.duration:.0f} s long, too short for a multi-position "
            f"session (needs >= {need:.0f} s: {init_static_s:.0f} s at rest, then at least "
            f"{min_orientations} orientations held 2-4 s; Tedaldi recommends 36-50)")

    det = _make_detector(imu, rate, init_static_s, window_s, min_interval_s)

    # Threshold scan: one accel fit per k, on interval sets that can determine it.
    scan: list[dict[str, Any]] = []
    fits: list[tuple[float, IntArray, _AccelFit, int]] = []
    most, most_distinct = 0, 0
    spread_error: ObservabilityError | None = None
    for k in threshold_multiples:
        iv = det.intervals(float(k))
        most = max(most, len(iv))
        entry: dict[str, Any] = {"k": float(k), "n_intervals": int(len(iv)), "chi2": None}
        scan.append(entry)
        if len(iv) < min_orientations:
            continue
        means, sig = _interval_stats(imu.accel, iv)
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
        fit = _fit_accel(means, sig, gravity, prior)
        if fit.ok:
            entry["chi2"] = fit.chi2 if fit.dof > 0 else None
            fits.append((float(k), iv, fit, n_distinct))
    if not fits:
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
    ranked = [f for f in fits if f[2].dof > 0]
    if ranked:
        best = min(ranked, key=lambda f: f[2].chi2)[2]
        tol = best.chi2 * (1.0 + 2.0 * np.sqrt(2.0 / best.dof))
        k_best, iv, afit, n_distinct = max((f for f in ranked if f[2].chi2 <= tol),
                                           key=lambda f: (len(f[1]), -f[2].chi2))
    else:
        # Exactly determined (as many intervals as parameters): nothing to rank by.
        k_best, iv, afit, n_distinct = fits[0]
    means, sig_int = _interval_stats(imu.accel, iv)

    # Gyro bias: mean over the initial static period (w = 0 there), combined with a prior.
    bg, bg_sd, density = _gyro_bias(imu.gyro[det.init_mask], rate)
    if prior is not None:
        v, s, used = prior.rows("gyro_bias")
        w_d, w_p = 1.0 / bg_sd**2, np.where(used, 1.0 / np.where(used, s, 1.0) ** 2, 0.0)
        bg = (w_d * bg + w_p * np.where(used, v, 0.0)) / (w_d + w_p)
        bg_sd = 1.0 / np.sqrt(w_d + w_p)

    # Gyro matrix: rotations between consecutive static intervals.
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
    # Residual noise: both gravity directions, angle random walk and bias error over the rotation.
    sig_rot = np.sqrt(sig_dir[:-1] ** 2 + sig_dir[1:] ** 2 + density**2 * dur
                      + float(np.mean(bg_sd**2)) * dur**2)
    gfit = _fit_gyro(gyro_pad, dt_pad, u[:-1], u[1:], sig_rot, bg, prior)

    a_sig = np.sqrt(np.clip(np.diag(afit.cov), 0.0, None))
    Ma_sig = np.zeros((3, 3))
    for k, (i, j) in enumerate(_LOWER):
        Ma_sig[i, j] = a_sig[k]
    ba_sig = a_sig[6:9]
    Mg_sig = np.sqrt(np.clip(np.diag(gfit.cov), 0.0, None)).reshape(3, 3)

    poor = _poor("accel_matrix", Ma_sig, lower_only=True)
    poor += [f"accel_bias[{i}] (sigma {s:.2g} m/s^2)" for i, s in enumerate(ba_sig)
             if not s <= POOR_SIGMA["accel_bias"]]
    poor += _poor("gyro_matrix", Mg_sig)
    poor += [f"gyro_bias[{i}] (sigma {s:.2g} rad/s)" for i, s in enumerate(bg_sd)
             if not s <= POOR_SIGMA["gyro_bias"]]
    for name, cond in (("accel", afit.condition), ("gyro", gfit.condition)):
        if not cond <= POOR_CONDITION:
            poor.append(f"{name} fit ill-conditioned (condition number {cond:.2g})")

    return MultiposResult(
        accel_matrix=M_a, accel_bias=b_a, gyro_matrix=gfit.M, gyro_bias=bg,
        accel_matrix_sigma=Ma_sig, accel_bias_sigma=ba_sig, gyro_matrix_sigma=Mg_sig,
        gyro_bias_sigma=bg_sd,
        accel_residual_rms=afit.rms, gyro_residual_rms=gfit.rms,
        threshold_multiple=k_best, n_static_intervals=len(iv),
        n_distinct_orientations=n_distinct,
        static_intervals=np.stack([imu.t[iv[:, 0]], imu.t[iv[:, 1]]], axis=1),
        poorly_determined=poor, accel_condition=afit.condition, gyro_condition=gfit.condition,
        accel_chi2=afit.chi2, gyro_chi2=gfit.chi2, gravity=float(gravity),
        session_time_ns=int(imu.stamps_ns()[0]),
        prior_source=None if prior is None else prior.source,
        threshold_scan=scan,
    )
