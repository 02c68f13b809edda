"""Degenerate motion: what a session cannot determine is reported as unobservable, never as a
number.

The position stage's marginal covariance can look confident along directions the motion does
not excite (the mocap's attitude noise, carried to the IMU through the lever arm, shapes its
whitening), and a fit can settle in the wrong one of two nearly equal minima. So the motion
itself is looked at too:

- **one rotation axis** (turntable, ground robot): the principal rates of the mocap's body rates
  show it. The lever arm along that axis never moves the IMU differently from the marker: it is
  unobservable. ``R_MI`` about the axis rests on the accelerometer alone; it is kept only when
  an independent closed-form fit (the angle about the axis scanned against the specific force)
  finds one clear angle and agrees with the calibration's;
- **too little excitation** (slow motion): a parameter whose reported sigma exceeds what would
  be of any use (``Parameter.useful_sigma``) is reported unobservable.

A session that leaves ``R_MI``, ``p_MI`` and the clock offset all undetermined is refused.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.model.parameters import (
    ACCEL_BIAS,
    COMPARED,
    GRAVITY_DIRECTION,
    GYRO_BIAS,
    ROTATION,
    TIME_OFFSET,
    TRANSLATION,
    Parameter,
)
from mocap_calib.core.prepare.kinematics import (
    SmoothedImu,
    mocap_grid,
    overlap,
    rotation_fit,
)
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.errors import ObservabilityError

Array = NDArray[np.float64]

#: Principal rates (RMS, rad/s) below this fraction of the largest: one rotation axis.
SINGLE_AXIS = 0.05
#: A closed-form angle is clear when every angle this far away (deg) fits this much worse.
CLEAR_AWAY_DEG = 30.0
CLEAR_RATIO = 1.5
#: Closed-form and calibrated R_MI may differ by this much (deg) beyond 5 sigma.
AGREE_DEG = 2.0
#: The order in which parameters are judged of use (the order their reasons are listed in).
USEFUL_ORDER: tuple[Parameter, ...] = (ROTATION, TRANSLATION, TIME_OFFSET, GRAVITY_DIRECTION,
                                       GYRO_BIAS, ACCEL_BIAS)
def _unobservable(r: CalibrationResult, p: Parameter, reason: str) -> CalibrationResult:
    """``r`` with ``p``'s value removed and the reason listed (unchanged when already so)."""
    e = r.estimate(p)
    if e.value is None:
        return r
    return replace(r.with_estimates({p: replace(e, value=None)}),
                   unobservable={**r.unobservable, p.name: reason})


def single_axis(s: PreparedSession, delta: float) -> Array | None:
    """The rotation axis (marker frame) when the body turned about one axis only, else None."""
    ov = overlap(s, delta, 0.5)
    if ov is None:
        return None
    gr = mocap_grid(s, s.R_WM, s.p_WM, *ov)
    w = gr.w_M[gr.ok]
    if len(w) < 100:
        return None
    _, sv, vt = np.linalg.svd(w, full_matrices=False)  # about the origin: a spin is one axis
    if sv[1] >= SINGLE_AXIS * sv[0]:
        return None
    return vt[0] * np.sign(vt[0][np.argmax(np.abs(vt[0]))])


def single_axis_rotation(s: PreparedSession, delta: float, axis: Array
                         ) -> tuple[Array, float] | None:
    """``R_MI`` from the gyro (up to the angle about ``axis``) and the accelerometer (that
    angle, scanned), with the contrast of the scan: the misfit of the best angle ``CLEAR_AWAY``
    away over the best's (below :data:`CLEAR_RATIO`: no clear angle)."""
    ov = overlap(s, delta, 0.5)
    if ov is None:
        return None
    gr = mocap_grid(s, s.R_WM, s.p_WM, *ov)
    imu = SmoothedImu.of(s)
    ok = gr.ok & imu.clear(gr.T - delta)
    g_I, f_I = imu.at(gr.T[ok] - delta)
    _, reflected, _, Q, _ = rotation_fit(g_I, gr.w_M[ok])
    if reflected:
        return None
    R_MW = np.transpose(gr.R[ok], (0, 2, 1))
    w, al = gr.w_M[ok], gr.alpha[ok]
    K = so3.hat(al) + np.einsum("nij,njk->nik", so3.hat(w), so3.hat(w))
    # Q f_I (rotated about the axis by phi) = R_MW a_W - R_MW g_W + K p + c: with the
    # marker's acceleration known, linear in (g_W, p, c).
    A = np.concatenate([-R_MW, K, np.broadcast_to(np.eye(3), R_MW.shape)], axis=2)
    M = A.reshape(-1, 9)
    Mi = np.linalg.pinv(M.T @ M, rcond=1e-12) @ M.T
    a_M = np.einsum("nij,nj->ni", R_MW, gr.a_W[ok])
    y = f_I @ Q.T
    y0 = np.outer(y @ axis, axis)
    y1, y2 = y - y0, np.cross(axis, y)
    phis = np.radians(np.arange(0.0, 360.0, 2.0))
    cost = np.empty(len(phis))
    for i, phi in enumerate(phis):
        t = (y0 + np.cos(phi) * y1 + np.sin(phi) * y2 - a_M).reshape(-1)
        cost[i] = float(np.sum((t - M @ (Mi @ t)) ** 2))
    k = int(np.argmin(cost))
    away = np.abs((np.degrees(phis - phis[k]) + 180.0) % 360.0 - 180.0) >= CLEAR_AWAY_DEG
    contrast = float(np.sqrt(cost[away].min() / max(cost[k], 1e-300)))
    return so3.exp(phis[k] * axis) @ Q, contrast


def mark_single_axis(r: CalibrationResult, s: PreparedSession, delta: float
                     ) -> tuple[CalibrationResult, Array | None]:
    """One rotation axis: the lever arm along it is unobservable, and ``R_MI`` too unless the
    accelerometer pins the angle about it (see the module doc). Returns the result so marked
    and the axis (marker frame) or None."""
    axis = single_axis(s, delta)
    if axis is None:
        return r, None
    shown = np.round(axis, 3).tolist()
    r = _unobservable(r, TRANSLATION, f"the body rotated about one axis only ({shown} in the "
                      "marker frame): the lever arm along it is not determined")
    q = r.value(ROTATION)
    if q is None:
        return r, axis
    cf = single_axis_rotation(s, delta, axis)
    if cf is None:
        return _unobservable(r, ROTATION, "the body rotated about one axis only: R_MI about it "
                             "is not determined"), axis
    R_cf, contrast = cf
    diff = float(np.degrees(np.linalg.norm(ROTATION.difference(ROTATION.state(q), R_cf))))
    sg = r.sigma(ROTATION)
    sig = 0.0 if sg is None else float(np.degrees(np.max(sg)))
    if contrast < CLEAR_RATIO or diff > 5 * sig + AGREE_DEG:
        r = _unobservable(r, ROTATION, f"the body rotated about one axis only ({shown} in the "
                          "marker frame): R_MI about it rests on the accelerometer alone, which "
                          f"does not pin it down (an independent fit differs by {diff:.1f} deg)")
    return r, axis


def single_axis_refusal(axis: Array, reasons: str) -> ObservabilityError:
    """The refusal of an implausible fit on one rotation axis: names the motion and what it
    cannot determine (the fit's failed checks follow in brackets)."""
    shown = np.round(axis, 3).tolist()
    return ObservabilityError(
        f"the body rotated about one axis only ({shown} in the marker frame: a turntable or a "
        "ground robot); such motion cannot tell the accelerometer bias along that axis from "
        "the direction of gravity (a fit may turn gravity upside down and take 2 g as bias), "
        f"nor determine the lever arm along it ({reasons}); record motion that tilts the "
        "body about all axes, or pass an earlier calibration of this IMU with --prior")


def mark_undetermined(r: CalibrationResult) -> CalibrationResult:
    """Parameters whose reported sigma is beyond any use (``Parameter.useful_sigma``) become
    unobservable; a session that leaves ``R_MI``, ``p_MI`` and the clock offset all
    undetermined is refused.

    Raises:
        ObservabilityError: nothing useful is determined.
    """
    for p in USEFUL_ORDER:
        e = r.estimate(p)
        if e.value is None or e.sigma is None:
            continue
        worst = float(np.max(np.atleast_1d(e.sigma)))
        if worst > p.useful_sigma:
            k, unit = p.printed.sigma_scale, p.printed.sigma_unit
            r = _unobservable(r, p, f"not determined to any use by this motion (sigma "
                              f"{k * worst:.3g} {unit}, useful below {k * p.useful_sigma:.3g} "
                              f"{unit}); record faster motion about all axes")
    if all(r.value(p) is None for p in COMPARED):
        raise ObservabilityError(
            "the motion determines none of R_MI, p_MI and the clock offset ("
            + "; ".join(f"{k}: {v}" for k, v in r.unobservable.items()
                        if k in {p.name for p in COMPARED})
            + "); record motion that rotates the body about all axes")
    return r
