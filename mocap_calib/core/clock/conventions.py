"""Convention check: is the data read the way it was written?

Sign, frame and quaternion conventions are the mistakes users of every calibration tool make
most often, and a fit that goes ahead anyway prints confident nonsense. When the base fit is
poor (or the clocks cannot be aligned at all), the common alternatives are tried on a stretch of
the session with a closed-form fit that takes milliseconds:

- readings of the mocap rotations: as given, conjugated (JPL quaternions, or ``R_MW``), inverted
  poses (``T_MW`` instead of ``T_WM``), the other quaternion order (xyzw / wxyz);
- for each, the gyro against the mocap's body rates: the best *orthogonal* map with a free
  scale (a reflection means a left-handed IMU frame, a scale of pi/180 a gyro in deg/s);
- the accelerometer against the mocap's acceleration: a linear fit of
  ``Q f_I = k R_MW a_W - R_MW g_W + (hat(alpha) + hat(w)^2) p + c`` with the position scale
  ``k`` free (``k = -1``: the accelerometer's sign is flipped; ``k = 0.01``: the positions are
  centimetres read as metres) and ``g_W`` free (``|g_W|`` near 1: an accelerometer in g).

The mistake is named only when a reading explains the data and the given one does not; nothing
is ever fixed silently. When no reading explains the data and the fit at the chosen clock offset
is no better than at offsets known to be wrong (chance), the two streams do not belong together.
The check costs nothing when the base fit is good: :func:`base_fit_poor` decides from the
stage 1-2 residuals the pipeline already has.

It belongs to aligning the two streams: each reading gets its own clock search (:mod:`.search`),
and where the data as given fit unambiguously at another offset than the search's, the
calibration starts there (the pipeline's first fits decide when the check runs).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.clock.search import search_clock
from mocap_calib.core.model import so3
from mocap_calib.core.policy import GRAVITY, POSITION_UNITS, STANDARD_GRAVITY
from mocap_calib.core.prepare.kinematics import (
    MocapGrid,
    SmoothedImu,
    mocap_grid,
    overlap,
    rotation_fit,
)
from mocap_calib.core.prepare.sensor_agreement import refuse_unmeasured_motion
from mocap_calib.core.prepare.session import PreparedSession, local_derivative
from mocap_calib.errors import InputError, ObservabilityError

Array = NDArray[np.float64]

#: A reading explains the data when the residuals are at most these fractions of the signal.
GOOD_ROTATION = 0.2
GOOD_FORCE = 0.3
#: ... and the base fit is poor (the check runs) above these fractions (stage 1-2 residuals).
POOR_ROTATION = 0.15
POOR_VELOCITY = 0.3
#: A fit no better than this fraction of its chance level (wrong clock offsets) is chance.
CHANCE = 0.6
#: A closed-form clock offset this far (s) from the coarse one replaces it as the start.
CLOCK_MOVE = 0.02
#: Below this angular-speed scatter (rad/s) the rotation fit cannot judge anything.
MIN_RATE_STD = 0.05

#: Readings of the mocap rotations (and positions) and the fix that goes with each.
READINGS: dict[str, str] = {
    "given": "",
    "conjugated": "the mocap quaternions look conjugated (JPL convention, or R_MW instead of "
                  "R_WM): conjugate them (negate their x, y, z)",
    "inverse": "the mocap poses look inverted (the inverse pose T_MW, the world in the marker "
               "frame, instead of T_WM): invert every pose",
    "xyzw": "the mocap quaternions look like xyzw (w last): pass --quat-order xyzw",
    "wxyz": "the mocap quaternions look like wxyz (w first): pass --quat-order wxyz",
}
#: Metres per unit, for naming the unit that the positions fit.


def read_as(kind: str, R: Array, p: Array) -> tuple[Array, Array]:
    """The mocap poses under another reading (see :data:`READINGS`)."""
    if kind == "given":
        return R, p
    Rt = np.transpose(R, (0, 2, 1))
    if kind == "conjugated":
        return Rt, p
    if kind == "inverse":  # T_MW = (R^T, -R^T p): the marker pose is its inverse
        return Rt, -np.einsum("nij,nj->ni", Rt, p)
    q = so3.rotmat_to_quat(R)
    order = [3, 0, 1, 2] if kind == "xyzw" else [1, 2, 3, 0]
    return so3.quat_to_rotmat(q[:, order]), p


@dataclass(frozen=True)
class Fit:
    """The closed-form fit of one reading at one clock offset.

    Attributes:
        t_d: the clock offset (s, relative to the raw stamps).
        rotation_ratio: RMS residual / RMS of the mocap's body rates (best orthogonal map,
            free scale).
        reflected: the best orthogonal map is a reflection (clearly better than any rotation).
        gyro_scale: mocap rate / gyro rate.
        force_ratio: RMS residual / RMS variation of the specific force.
        position_scale: ``k``: metres per unit the positions are read in, relative to the
            reading (1: right; negative: the accelerometer's sign is flipped).
        gravity: ``|g_W|`` fitted (m/s^2 as read from the accelerometer).
        k_known, g_known: whether the motion determines ``position_scale`` and ``gravity``
            (a turntable about the vertical shows neither).
    """

    t_d: float
    rotation_ratio: float
    reflected: bool
    gyro_scale: float
    force_ratio: float
    position_scale: float
    gravity: float
    k_known: bool = True
    g_known: bool = True
    k_sign_known: bool = True
    runner_up: float = float("inf")  # score of the best fit more than a second away

    @property
    def score(self) -> float:
        return self.rotation_ratio + self.force_ratio

    def fits(self) -> bool:
        return self.rotation_ratio < GOOD_ROTATION and self.force_ratio < GOOD_FORCE


def _near(x: float, target: float, tol: float = 0.15) -> bool:
    return target != 0 and abs(x / target - 1.0) < tol


def fit_reading(s: PreparedSession, R: Array, p: Array, t_d: float,
                imu: SmoothedImu | None = None, refine: bool = True,
                gravity: float = GRAVITY) -> Fit | None:
    """The closed-form fit of the mocap poses ``R``, ``p`` (one reading) near offset ``t_d``
    (refined within +-0.3 s by the rotation fit when ``refine``)."""
    imu = imu or SmoothedImu.of(s)
    span = 0.3 if refine else 0.0
    delta = s.clock_shift + t_d
    ov = overlap(s, delta, 0.5 + span)
    if ov is None:
        return None
    gr = mocap_grid(s, R, p, *ov)
    ok = gr.ok & imu.clear(gr.T - delta)
    if ok.sum() < 200 or float(np.std(gr.w_M[ok], axis=0).max()) < MIN_RATE_STD:
        return None
    if refine:
        shifts = np.arange(-span, span + 1e-9, 0.02)
        ratios = [rotation_fit(imu.at(gr.T[ok] - delta - d)[0], gr.w_M[ok])[0]
                  for d in shifts]
        k = int(np.argmin(ratios))
        d = shifts[k]
        if 0 < k < len(shifts) - 1:  # parabola through the three best
            r0, r1, r2 = ratios[k - 1], ratios[k], ratios[k + 1]
            den = r0 - 2 * r1 + r2
            if den > 0:
                d += 0.5 * (r0 - r2) / den * 0.02
        t_d, delta = t_d + float(d), delta + float(d)
    g_I, f_I = imu.at(gr.T[ok] - delta)
    rot_ratio, reflected, scale, Q, b = rotation_fit(g_I, gr.w_M[ok])
    force = _force(gr, ok, f_I @ Q.T, b, gravity)
    return Fit(float(t_d), rot_ratio, reflected, scale, force.ratio, force.k, force.g,
               force.k_known, force.g_known, force.k_sign_known)


@dataclass(frozen=True)
class _Force:
    ratio: float
    k: float
    g: float
    k_known: bool
    g_known: bool
    k_sign_known: bool = True


def _force(gr: MocapGrid, ok: NDArray[np.bool_], y: Array, b: Array,
           gravity: float) -> _Force:
    """Specific force ``y = Q f_I = k R_MW a_W - R_MW g_W + K p + c``, linear in
    ``(k, g_W, p, c)``; about one axis only ``Q`` is free about that axis, and the angle is
    scanned (the accelerometer decides)."""
    R_MW = np.transpose(gr.R[ok], (0, 2, 1))
    w, al = gr.w_M[ok], gr.alpha[ok]
    K = so3.hat(al) + np.einsum("nij,njk->nik", so3.hat(w), so3.hat(w))
    A = np.zeros((len(R_MW), 3, 10))
    A[:, :, 0] = np.einsum("nij,nj->ni", R_MW, gr.a_W[ok])
    A[:, :, 1:4] = -R_MW
    A[:, :, 4:7] = K
    A[:, :, 7:10] = np.eye(3)
    M = A.reshape(-1, 10)
    H = M.T @ M
    Hi = np.linalg.pinv(H, rcond=1e-12)
    var = float(np.sum((y - y.mean(axis=0)) ** 2))
    sw = np.linalg.svd(b, compute_uv=False)
    if sw[1] >= 0.1 * sw[0]:
        return _solve(M, H, Hi, y.reshape(-1), var, gravity)
    # One rotation axis n: rows rotated by phi about n, y(phi) = y0 + cos y1 + sin y2.
    n = np.linalg.svd(b, full_matrices=False)[2][0]
    y0 = np.outer(y @ n, n)
    y1, y2 = y - y0, np.cross(n, y)
    trials = []
    for phi in np.radians(np.arange(0.0, 360.0, 5.0)):
        yp = (y0 + np.cos(phi) * y1 + np.sin(phi) * y2).reshape(-1)
        trials.append(_solve(M, H, Hi, yp, var, gravity))
    best = min(trials, key=lambda f: f.ratio)
    other = [f for f in trials if np.sign(f.k) != np.sign(best.k)]
    sign_known = not other or min(f.ratio for f in other) > 1.2 * best.ratio + 0.01
    return _Force(best.ratio, best.k if sign_known else abs(best.k), best.g, best.k_known,
                  best.g_known, sign_known)


def _solve(M: Array, H: Array, Hi: Array, y: Array, var: float, gravity: float) -> _Force:
    """Least squares; a parameter is known when moving it by 1 (``k``) or 1 m/s^2 (``|g|``)
    would at least double the misfit: ``sqrt(RSS (H^-1)_jj)`` below that. ``k`` is taken with
    ``|g_W|`` held at ``gravity`` (along the fitted direction): free, the two can trade off
    against each other when the model misses something (an accelerometer scale error)."""
    My = M.T @ y
    x = Hi @ My
    yy = float(y @ y)
    rss = max(yy - 2.0 * float(x @ My) + float(x @ H @ x), 0.0)
    g = x[1:4]
    gn = float(np.linalg.norm(g))
    gd = g / max(gn, 1e-9)
    sig_g = float(np.sqrt(max(rss * (gd @ Hi[1:4, 1:4] @ gd), 0.0)))
    k, sig_k = float(x[0]), float(np.sqrt(max(rss * Hi[0, 0], 0.0)))
    if gn > 1.0:
        idx, gi = [0, 4, 5, 6, 7, 8, 9], [1, 2, 3]
        gf = gravity * gd
        b = My[idx] - H[np.ix_(idx, gi)] @ gf
        H2 = H[np.ix_(idx, idx)]
        H2i = np.linalg.pinv(H2, rcond=1e-12)
        x2 = H2i @ b
        y2 = yy - 2.0 * float(gf @ My[gi]) + float(gf @ H[np.ix_(gi, gi)] @ gf)
        rss2 = max(y2 - 2.0 * float(x2 @ b) + float(x2 @ H2 @ x2), 0.0)
        k, sig_k = float(x2[0]), float(np.sqrt(max(rss2 * H2i[0, 0], 0.0)))
    # A direction the motion does not excite at all: pinv gives it no variance; check it.
    null = np.linalg.eigh(H)
    weak = null[1][:, null[0] <= 1e-9 * null[0][-1]]
    k_free = weak.size and np.abs(weak[0]).max() > 1e-3
    g_free = weak.size and np.abs(gd @ weak[1:4]).max() > 1e-3
    return _Force(float(np.sqrt(rss / max(var, 1e-12))), k, gn,
                  bool(sig_k < 0.3 and not k_free), bool(sig_g < 1.0 and not g_free))


def _best(s: PreparedSession, R: Array, p: Array, offsets: list[float],
          imu: SmoothedImu, gravity: float = GRAVITY) -> Fit | None:
    """The best fit over the offsets, with the score of the best one over a second away
    (``runner_up``: a clock offset is unambiguous when that is clearly worse)."""
    fits = [f for f in (fit_reading(s, R, p, t, imu, gravity=gravity) for t in offsets)
            if f is not None]
    if not fits:
        return None
    best = min(fits, key=lambda f: f.score)
    far = [f.score for f in fits if abs(f.t_d - best.t_d) > 1.0]
    return replace(best, runner_up=min(far, default=float("inf")))


def _offsets(s: PreparedSession, R: Array, p: Array, known: list[float],
             max_offset: float | None) -> list[float]:
    """Clock offsets to try: the known candidates and this reading's own search's."""
    out = list(known)
    try:
        found = search_clock(s.u, s.gyro, s.accel, s.tau, R, p, s.clock_shift, max_offset)
        out += [t for t, _ in found.candidates]
    except ObservabilityError:
        pass
    return list(dict.fromkeys(round(t, 4) for t in out))[:8]


def _chance(s: PreparedSession, R: Array, p: Array, t_d: float,
            imu: SmoothedImu) -> float | None:
    """Median score at clock offsets seconds away from ``t_d`` (known to be wrong)."""
    scores = [f.score for f in (fit_reading(s, R, p, t_d + d, imu, refine=False)
                                for d in (-9.0, -6.0, -4.0, 4.0, 6.0, 9.0)) if f is not None]
    return float(np.median(scores)) if len(scores) >= 2 else None


def _unit_name(metres: float) -> str:
    names = {"m": "metres", "cm": "centimetres", "mm": "millimetres"}
    for u, m in POSITION_UNITS.items():
        if _near(metres, m, 0.01):
            return names[u]
    return f"units of {metres:g} m"


def _parameter_fixes(fit: Fit, gravity: float, position_unit_m: float = 1.0) -> list[str]:
    """What the parameters of a fitting reading say is wrong (empty: nothing). Only what the
    motion determines is judged."""
    fixes = []
    if fit.reflected:
        fixes.append("the IMU's axes look left-handed (one axis of both the gyro and the "
                     "accelerometer flipped, e.g. the y axis): negate that axis in both "
                     "sensors (the data cannot tell which one; check the IMU driver)")
    if _near(fit.gyro_scale, np.pi / 180, 0.1):
        fixes.append("the gyro looks like it is in deg/s: pass --gyro-unit deg/s")
    elif _near(fit.gyro_scale, 180 / np.pi, 0.1):
        fixes.append("the gyro looks like it is in rad/s, not deg/s: pass --gyro-unit rad/s")
    k, g = fit.position_scale, fit.gravity
    if fit.g_known and _near(g, gravity / STANDARD_GRAVITY, 0.2):
        fixes.append("the accelerometer looks like it is in g: pass --accel-unit g")
        return fixes
    if not fit.k_known or (fit.g_known and not _near(g, gravity, 0.2)):
        return fixes  # the specific-force fit does not pin the scale down: judge nothing
    if fit.k_sign_known and k < 0 and _near(-k, 1.0, 0.3):
        fixes.append("the accelerometer's sign looks flipped (it reads minus the specific "
                     "force, e.g. -g when level): negate the accelerometer readings")
    metres = abs(k) * position_unit_m
    hit = [u for u, m in POSITION_UNITS.items() if _near(metres, m, 0.3)]
    # Only a unit the data fit is named (never a guess): other scales are not a unit mistake.
    if hit and not _near(abs(k), 1.0, 0.3):
        fixes.append(f"the mocap positions look like {_unit_name(POSITION_UNITS[hit[0]])}, "
                     f"not {_unit_name(position_unit_m)}: pass --position-unit {hit[0]}")
    return fixes


def check_conventions(s: PreparedSession, offsets: list[float], gravity: float = GRAVITY,
                      max_offset: float | None = None, position_unit_m: float = 1.0
                      ) -> Fit | None:
    """Try the common readings of the data; raise naming the mistake, or the mismatch.

    Args:
        s: the prepared session.
        offsets: candidate clock offsets ``t_d`` (s) to try (e.g. the clock search's).
        gravity: the assumed ``|g|``.
        max_offset: the user's limit on the clock offset search.
        position_unit_m: metres per unit the positions were declared in (for the hint).

    Returns:
        The fit of the data as given, when it explains them (None otherwise).

    Raises:
        InputError: a reading other than the given one, or the given one with other units,
            signs or handedness, explains the data (and the given one does not).
        ObservabilityError: no reading does, and the gyro follows the poses while the
            accelerometer does not (:mod:`~mocap_calib.core.prepare.sensor_agreement`), or
            the best agreement is no better than chance (the streams are not of the same
            stretch of the same recording).
    """
    imu = SmoothedImu.of(s)
    fits: dict[str, Fit] = {}
    for kind in READINGS:
        R, p = read_as(kind, s.R_WM, s.p_WM)
        f = _best(s, R, p, _offsets(s, R, p, offsets, max_offset), imu, gravity)
        if f is not None:
            fits[kind] = f
    if not fits:
        return None
    fixes = {k: _parameter_fixes(f, gravity, position_unit_m) for k, f in fits.items()}
    good = [k for k in fits if fits[k].fits()]
    if "given" in good and not fixes["given"]:
        return fits["given"]
    if good:
        clean = [k for k in good if not fixes[k]] or good
        best = min(clean, key=lambda k: fits[k].score)
        if best != "given" and "given" in good:
            return None  # the data as given fit too (only their parameters are off): unclear
        named = ([READINGS[best]] if best != "given" else []) + fixes[best]
        raise InputError("; ".join(named) + " (the data as they are read do not fit)")
    if "given" in fits:  # the gyro follows the poses, the accelerometer does not: say so
        refuse_unmeasured_motion(s, fits["given"].t_d, gravity)
    best = min(fits, key=lambda k: fits[k].score)
    R, p = read_as(best, s.R_WM, s.p_WM)
    chance = _chance(s, R, p, fits[best].t_d, imu)
    if chance is not None and fits[best].score > CHANCE * chance:
        raise ObservabilityError(
            "the IMU and mocap streams do not match at any clock offset (their agreement is no "
            "better than chance): check that both files are from the same recording and "
            "overlap in time")
    return None


def base_fit_poor(s: PreparedSession, spacing: float, rms_attitude_rad: float,
                  rms_velocity: float) -> bool:
    """Whether the stage 1-2 residuals are a large fraction of the motion itself (the
    relative rotations and velocity changes between keyframes): then the data may be read
    the wrong way, and :func:`check_conventions` runs."""
    k = np.unique(np.searchsorted(s.tau, np.arange(s.tau[0], s.tau[-1], spacing)))
    k = k[k < len(s.tau)]
    if len(k) < 4:
        return False
    dR = np.einsum("nji,njk->nik", s.R_WM[k[:-1]], s.R_WM[k[1:]])
    rot = float(np.sqrt(np.mean(np.sum(so3.log(dR) ** 2, axis=1)) / 3))
    half = max(2, int(round(0.05 * s.mocap_rate)))
    _, v, valid = local_derivative(s.tau, s.p_WM, half, s.gap)
    dv = np.diff(v[k], axis=0)[valid[k[:-1]] & valid[k[1:]]]
    vel = float(np.sqrt(np.mean(dv**2))) if len(dv) else 0.0
    return (rot > 0 and rms_attitude_rad > POOR_ROTATION * rot) or (
        vel > 0 and rms_velocity > POOR_VELOCITY * vel)
