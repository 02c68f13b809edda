"""Attitude-drift check: does a calibration make gyro integration drift less?

Over a segment ``[t0, t1]`` that was not used for calibration, the gyro is integrated (RK4 on
quaternions) twice from the same initial attitude: raw (``w = w_m``) and calibrated
(``w = M_g^-1 (w_m - b_g - G f)``). Roll and pitch, the attitude angles gravity makes
observable, are compared with a reference at ``t1`` (or along a reference series). Yaw is not
compared: it needs a heading reference that an accel-only reference cannot give.

Both integrations start from, and are compared with, the same attitudes, so the difference
isolates the gyro calibration. When no mocap attitude is given, the IMU must rest at ``t0``
(and ``t1``) and its (calibrated, if possible) accel gives roll and pitch there.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mocap_calib.core.model import rest, so3
from mocap_calib.core.model.preint import quat_cumprod, quat_increments, sample_nodes
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.errors import InputError, ObservabilityError

Array = NDArray[np.float64]

_DOWN = np.array([0.0, 0.0, -1.0])

#: Limits for "the IMU rests" when an attitude is taken from the accel.
_STATIC_ACCEL_STD = 0.2  # m/s^2 per axis
_STATIC_GYRO = 0.05  # rad/s, |mean corrected rate|


def _opt(value: ArrayLike | None, shape: tuple[int, ...], name: str) -> Array | None:
    if value is None:
        return None
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise InputError(f"calibration: '{name}' must be {shape} finite numbers, got shape "
                         f"{arr.shape}")
    return arr


@dataclass(frozen=True)
class GyroCalibration:
    """The corrections applied to the gyro (and to the accel used for reference attitudes).

    Attributes:
        gyro_bias: ``b_g`` in rad/s.
        gyro_matrix: ``M_g`` in ``w_m = M_g w + G f + b_g`` (None: identity).
        g_sensitivity: ``G`` in rad/s per m/s^2 (None: zero).
        accel_bias: ``b_a`` in m/s^2 (None: zero).
        accel_matrix: ``M_a`` in ``a_m = M_a f + b_a`` (None: identity).
    """

    gyro_bias: Array
    gyro_matrix: Array | None = None
    g_sensitivity: Array | None = None
    accel_bias: Array | None = None
    accel_matrix: Array | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "gyro_bias", _opt(self.gyro_bias, (3,), "gyro_bias"))
        for name, shape in (("gyro_matrix", (3, 3)), ("g_sensitivity", (3, 3)),
                            ("accel_bias", (3,)), ("accel_matrix", (3, 3))):
            object.__setattr__(self, name, _opt(getattr(self, name), shape, name))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> GyroCalibration:
        """From a calibration result or intrinsics dict (keys of ``docs/conventions.md``;
        other keys and ``null`` values are ignored)."""
        if d.get("gyro_bias") is None:
            raise InputError("calibration: no 'gyro_bias'; give a calibration result or "
                             "multipos intrinsics")
        keys = ("gyro_matrix", "g_sensitivity", "accel_bias", "accel_matrix")
        return cls(d["gyro_bias"], **{k: d.get(k) for k in keys})

    def with_bias_drift(self, rate: Array, dt: float) -> GyroCalibration:
        """The calibration ``dt`` seconds after the middle of its session, for a gyro bias
        that drifts at ``rate`` (rad/s^2): ``b_g(t) = b_g + r_g (t - t_mid)``."""
        return replace(self, gyro_bias=self.gyro_bias + np.asarray(rate, dtype=float) * dt)

    def specific_force(self, accel: Array) -> Array:
        """Calibrated specific force ``f = M_a^-1 (a_m - b_a)``."""
        f = accel - (self.accel_bias if self.accel_bias is not None else 0.0)
        if self.accel_matrix is not None:
            f = f @ np.linalg.inv(self.accel_matrix).T
        return f

    def angular_velocity(self, gyro: Array, accel: Array) -> Array:
        """Calibrated body rate ``w = M_g^-1 (w_m - b_g - G f)``."""
        w = gyro - self.gyro_bias
        if self.g_sensitivity is not None:
            w = w - self.specific_force(accel) @ self.g_sensitivity.T
        if self.gyro_matrix is not None:
            w = w @ np.linalg.inv(self.gyro_matrix).T
        return w


@dataclass(frozen=True)
class AttitudeDriftResult:
    """Roll/pitch drift of gyro integration over one segment, raw and calibrated.

    Attributes:
        t0: start of the segment (s, IMU clock; the first sample at or after the request).
        t1: end of the segment (the last sample at or before the request).
        roll_drift_raw_deg: integrated minus reference roll at ``t1``, raw gyro.
        pitch_drift_raw_deg: same for pitch.
        tilt_drift_raw_deg: angle between integrated and reference gravity directions.
        roll_drift_cal_deg: integrated minus reference roll at ``t1``, calibrated gyro.
        pitch_drift_cal_deg: same for pitch.
        tilt_drift_cal_deg: angle between integrated and reference gravity directions.
        reduction: ``1 - tilt_cal / tilt_raw`` (1: all drift removed; negative: worse).
        initial_source: where the initial attitude came from (``given``, ``reference``,
            ``accel``).
        reference_source: where the reference at ``t1`` came from.
        series_t: (m,) reference times inside the segment (empty without a series).
        series_tilt_raw_deg: (m,) tilt drift along the series, raw gyro.
        series_tilt_cal_deg: (m,) tilt drift along the series, calibrated gyro.
    """

    t0: float
    t1: float
    roll_drift_raw_deg: float
    pitch_drift_raw_deg: float
    tilt_drift_raw_deg: float
    roll_drift_cal_deg: float
    pitch_drift_cal_deg: float
    tilt_drift_cal_deg: float
    reduction: float
    initial_source: str
    reference_source: str
    series_t: Array
    series_tilt_raw_deg: Array
    series_tilt_cal_deg: Array

    @property
    def duration(self) -> float:
        return self.t1 - self.t0

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {k: float(getattr(self, k)) for k in (
            "t0", "t1", "roll_drift_raw_deg", "pitch_drift_raw_deg", "tilt_drift_raw_deg",
            "roll_drift_cal_deg", "pitch_drift_cal_deg", "tilt_drift_cal_deg", "reduction")}
        d["duration"] = float(self.duration)
        d["initial_source"] = self.initial_source
        d["reference_source"] = self.reference_source
        if len(self.series_t):
            d["series"] = {"t": self.series_t.tolist(),
                           "tilt_raw_deg": self.series_tilt_raw_deg.tolist(),
                           "tilt_cal_deg": self.series_tilt_cal_deg.tolist()}
        return d


def roll_pitch(R_WI: Array, g_dir: Array) -> tuple[Array, Array]:
    """Roll and pitch (rad, ZYX convention) of ``R_WI`` relative to gravity ``g_dir`` in ``W``.

    Uses the body "up" vector ``u = -R_WI^T g_dir``: ``roll = atan2(u_y, u_z)``,
    ``pitch = atan2(-u_x, sqrt(u_y^2 + u_z^2))``.
    """
    u = -np.einsum("...ji,j->...i", R_WI, g_dir)
    roll = np.arctan2(u[..., 1], u[..., 2])
    pitch = np.arctan2(-u[..., 0], np.hypot(u[..., 1], u[..., 2]))
    return roll, pitch


def _wrap_deg(a: Array | float) -> Array:
    return (np.asarray(a) + 180.0) % 360.0 - 180.0


def _tilt_deg(R_a: Array, R_b: Array, g_dir: Array) -> Array:
    ua = np.einsum("...ji,j->...i", R_a, g_dir)
    ub = np.einsum("...ji,j->...i", R_b, g_dir)
    c = np.clip(np.sum(ua * ub, axis=-1), -1.0, 1.0)
    return np.degrees(np.arccos(c))


def _attitude_from_accel(imu: ImuSamples, t: float, window_s: float, cal: GyroCalibration,
                         g_dir: Array, what: str, fix: str) -> Array:
    """Roll/pitch attitude (yaw 0) from the accel around ``t``; the IMU must rest."""
    sel = np.abs(imu.t - t) <= 0.5 * window_s
    if sel.sum() < 5:
        raise InputError(f"{what}: fewer than 5 IMU samples within {window_s:g} s of t={t:g} s")
    f = cal.specific_force(imu.accel[sel])
    w = cal.angular_velocity(imu.gyro[sel], imu.accel[sel])
    check = rest.window_rest(f, w, _STATIC_ACCEL_STD, _STATIC_GYRO)
    if not check.at_rest:
        raise ObservabilityError(
            f"{what}: the IMU is not at rest around t={t:.2f} s (accel std "
            f"{check.accel_std:.2g} m/s^2, rate {np.degrees(check.rate):.2g} deg/s), so the "
            f"accel cannot give its attitude; {fix}")
    up = f.mean(axis=0)
    # R_WI maps the body up vector onto world up (-g_dir); yaw is arbitrary (0).
    return so3.rotation_between(up, -g_dir)


def reference_on_imu_times(imu_t: Array, t_ref: Array, R_ref: Array, t0: float, t1: float,
                           gap_factor: float = 2.5, segment_names: tuple[str, str] = ("t0", "t1")
                           ) -> tuple[Array, Array]:
    """Reference attitudes (e.g. mocap ``R_WM R_MI``) moved onto IMU sample times in
    ``[t0, t1]``.

    :func:`attitude_drift_check` compares the integrated attitude at the first IMU sample at or
    after each reference time; with the reference on IMU stamps that comparison is exact
    instead of up to one IMU period late (which, in fast rotation, reads as drift). Attitudes
    are interpolated geodesically between the neighbouring reference samples, at about the
    reference rate (plus both segment ends); IMU times inside a reference gap (a step longer
    than ``gap_factor`` median steps) are left out.

    Args:
        segment_names: how messages name the segment's start and end (a CLI: its options).

    Raises:
        InputError: the segment starts or ends inside a gap of the reference.
    """
    i0 = int(np.searchsorted(imu_t, t0, side="left"))
    i1 = int(np.searchsorted(imu_t, t1, side="right")) - 1
    if i1 <= i0:
        raise InputError(f"segment [{t0:g}, {t1:g}] s holds fewer than 2 IMU samples")
    dt_ref = np.diff(t_ref)
    step = max(1, int(round(float(np.median(dt_ref)) / float(np.median(np.diff(imu_t))))))
    idx = np.unique(np.concatenate([np.arange(i0, i1 + 1, step), [i0, i1]]))
    t = imu_t[idx]
    j = np.clip(np.searchsorted(t_ref, t, side="right"), 1, len(t_ref) - 1)
    gap = dt_ref[j - 1] > gap_factor * float(np.median(dt_ref))
    for end, what, name in ((0, "start", segment_names[0]), (-1, "end", segment_names[1])):
        if gap[end]:
            raise InputError(f"the mocap has a gap ({dt_ref[j[end] - 1]:.2f} s) at the "
                             f"segment's {what} (t={t[end]:.3f} s on the IMU clock); move "
                             f"{name} to where the marker is tracked")
    keep = ~gap
    t, j = t[keep], j[keep]
    a = j - 1
    frac = np.clip((t - t_ref[a]) / (t_ref[j] - t_ref[a]), 0.0, 1.0)
    Ra = R_ref[a]
    rel = so3.log(np.einsum("nji,njk->nik", Ra, R_ref[j]))
    return t, Ra @ so3.exp(frac[:, None] * rel)


def _interp_attitude(t_ref: Array, R_ref: Array, t: float) -> Array:
    """Attitude at ``t`` from a series, by geodesic interpolation between neighbours."""
    i = int(np.clip(np.searchsorted(t_ref, t), 1, len(t_ref) - 1))
    t_a, t_b = t_ref[i - 1], t_ref[i]
    s = 0.0 if t_b == t_a else float(np.clip((t - t_a) / (t_b - t_a), 0.0, 1.0))
    return R_ref[i - 1] @ so3.exp(s * so3.log(R_ref[i - 1].T @ R_ref[i]))


def _segment(imu: ImuSamples, t0: float, t1: float) -> tuple[int, int]:
    """First and last sample index of ``[t0, t1]``."""
    if not t1 > t0:
        raise InputError(f"segment [{t0:g}, {t1:g}] s: t1 must be after t0")
    i0 = int(np.searchsorted(imu.t, t0, side="left"))
    i1 = int(np.searchsorted(imu.t, t1, side="right")) - 1
    if i0 >= len(imu) or i1 <= i0:
        raise InputError(f"segment [{t0:g}, {t1:g}] s holds fewer than 2 IMU samples (the log "
                         f"spans {imu.t[0]:g}-{imu.t[-1]:g} s)")
    return i0, i1


def _series(reference_series: tuple[ArrayLike, ArrayLike] | None, ta: float, tb: float
            ) -> tuple[Array, Array]:
    """The checked reference series (empty without one); it must cover ``[ta, tb]``."""
    if reference_series is None:
        return np.zeros(0), np.zeros((0, 3, 3))
    series_t = np.asarray(reference_series[0], dtype=float)
    series_R = np.asarray(reference_series[1], dtype=float)
    if series_t.ndim != 1 or series_R.shape != (len(series_t), 3, 3) or len(series_t) < 2:
        raise InputError("reference_series: give (t (m,), R_WI (m, 3, 3)) with m >= 2")
    if np.any(np.diff(series_t) <= 0):
        raise InputError("reference_series: times must be strictly increasing")
    if series_t[0] > ta or series_t[-1] < tb:
        raise InputError(f"reference_series spans {series_t[0]:g}-{series_t[-1]:g} s, not "
                         f"the whole segment [{ta:g}, {tb:g}] s")
    return series_t, series_R


def _integrate(R0: Array, w: Array, t: Array) -> Array:
    """Attitudes at every sample from ``R0``, RK4 with the rate linear between samples."""
    q = quat_cumprod(quat_increments(sample_nodes(w), np.diff(t)))
    return np.concatenate([R0[None], R0 @ so3.quat_to_rotmat(q)])


def _unit_gravity(gravity_dir: ArrayLike) -> Array:
    g_dir = np.asarray(gravity_dir, dtype=float)
    if g_dir.shape != (3,) or not np.linalg.norm(g_dir) > 0:
        raise InputError("gravity_dir must be a non-zero 3-vector")
    return g_dir / np.linalg.norm(g_dir)


def _given_attitude(given: ArrayLike, what: str) -> Array:
    R = np.asarray(given, dtype=float)
    if R.shape != (3, 3) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6):
        raise InputError(f"{what}: must be a 3x3 rotation matrix R_WI")
    return R


def _drift_at_end(R_end: Array, R_ref: Array, g_dir: Array) -> tuple[float, float, float]:
    """Roll, pitch (wrapped) and tilt difference in deg of an integrated attitude."""
    roll_ref, pitch_ref = roll_pitch(R_ref, g_dir)
    roll, pitch = roll_pitch(R_end, g_dir)
    return (float(_wrap_deg(np.degrees(roll - roll_ref))),
            float(_wrap_deg(np.degrees(pitch - pitch_ref))),
            float(_tilt_deg(R_end, R_ref, g_dir)))


def attitude_drift_check(
    imu: ImuSamples,
    t0: float,
    t1: float,
    calibration: GyroCalibration | Mapping[str, Any],
    *,
    initial_attitude: ArrayLike | None = None,
    reference_attitude: ArrayLike | None = None,
    reference_series: tuple[ArrayLike, ArrayLike] | None = None,
    gravity_dir: ArrayLike = _DOWN,
    static_window_s: float = 1.0,
    not_at_rest_fix: str = "give a mocap attitude or choose a time when the IMU rests",
) -> AttitudeDriftResult:
    """Integrate the gyro over ``[t0, t1]`` raw and calibrated and compare roll/pitch drift.

    Args:
        imu: IMU samples containing the segment.
        t0: start of the segment (s, IMU clock); not used for the calibration.
        t1: end of the segment.
        calibration: the corrections (or a result dict with ``gyro_bias`` and optionally
            ``gyro_matrix``, ``g_sensitivity``, ``accel_bias``, ``accel_matrix``).
        initial_attitude: ``R_WI(t0)`` (3x3), e.g. from mocap; default: from
            ``reference_series`` if given, else from the accel (the IMU must rest at ``t0``).
        reference_attitude: ``R_WI(t1)`` (3x3); default: from ``reference_series`` if given,
            else from the accel (the IMU must rest at ``t1``).
        reference_series: ``(t, R_WI)`` with times (m,) on the IMU clock and (m, 3, 3)
            attitudes, e.g. mocap ``R_WM R_MI``; the drift is also reported along it.
        gravity_dir: unit gravity direction in ``W`` (default ``-z``).
        static_window_s: window around ``t0``/``t1`` over which the accel is averaged.
        not_at_rest_fix: the fix named when the IMU is not at rest where the accel must give
            an attitude (a CLI names its options).

    Returns:
        Roll, pitch and tilt drift at ``t1`` (deg) for the raw and the calibrated gyro, the
        reduction, and the drift along the reference series.

    Raises:
        InputError: bad segment, attitudes or calibration.
        ObservabilityError: an attitude must come from the accel but the IMU is not at rest.
    """
    cal = GyroCalibration.from_dict(calibration) if isinstance(calibration, Mapping) \
        else calibration
    g_dir = _unit_gravity(gravity_dir)
    i0, i1 = _segment(imu, t0, t1)
    series_t, series_R = _series(reference_series, float(imu.t[i0]), float(imu.t[i1]))

    def attitude(given: ArrayLike | None, t: float, what: str) -> tuple[Array, str]:
        if given is not None:
            return _given_attitude(given, what), "given"
        if len(series_t):
            return _interp_attitude(series_t, series_R, t), "reference"
        return _attitude_from_accel(imu, t, static_window_s, cal, g_dir, what,
                                    not_at_rest_fix), "accel"

    R0, src0 = attitude(initial_attitude, float(imu.t[i0]), "initial attitude")
    R1, src1 = attitude(reference_attitude, float(imu.t[i1]), "reference attitude")

    seg = slice(i0, i1 + 1)
    R_path = {key: _integrate(R0, w, imu.t[seg]) for key, w in (
        ("raw", imu.gyro[seg]), ("cal", cal.angular_velocity(imu.gyro[seg], imu.accel[seg])))}
    roll_raw, pitch_raw, raw = _drift_at_end(R_path["raw"][-1], R1, g_dir)
    roll_cal, pitch_cal, tilt_cal = _drift_at_end(R_path["cal"][-1], R1, g_dir)

    inside = (series_t >= imu.t[i0]) & (series_t <= imu.t[i1])
    s_t = series_t[inside]
    k = np.clip(np.searchsorted(imu.t[seg], s_t), 0, i1 - i0)
    s_raw = _tilt_deg(R_path["raw"][k], series_R[inside], g_dir)
    s_cal = _tilt_deg(R_path["cal"][k], series_R[inside], g_dir)

    reduction = 1.0 - tilt_cal / raw if raw > 0 else 0.0
    return AttitudeDriftResult(
        t0=float(imu.t[i0]), t1=float(imu.t[i1]),
        roll_drift_raw_deg=roll_raw, pitch_drift_raw_deg=pitch_raw, tilt_drift_raw_deg=raw,
        roll_drift_cal_deg=roll_cal, pitch_drift_cal_deg=pitch_cal, tilt_drift_cal_deg=tilt_cal,
        reduction=float(reduction), initial_source=src0, reference_source=src1,
        series_t=s_t, series_tilt_raw_deg=s_raw, series_tilt_cal_deg=s_cal)
