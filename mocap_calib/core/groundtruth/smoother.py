"""IMU ground truth from mocap and a calibration: the IMU's pose, velocity and biases in a
gravity-aligned world, on the IMU clock.

The mocap poses are mapped through the calibration (``T_GI = R_GW T_WM T_MI`` at IMU-clock
time ``t_mocap - t_d``, with ``R_GW`` the smallest rotation taking ``g_W`` to -z) and fused with
the IMU by an error-state Kalman filter and a Rauch-Tung-Striebel smoother: the IMU (corrected
by the calibrated intrinsics) carries the motion between and across mocap samples, the mocap
anchors it, and the biases are random-walk states. Interpolating the mocap alone would pass
its noise (0.05 deg per sample is typical) straight into the ground truth; the smoother averages
it out and bridges short occlusions with the IMU.

Every output sample carries its smoothed 1-sigma; samples whose position or attitude sigma
exceeds the limits (long mocap gaps, the ends) are left out and reported, with every mocap gap
and whether it was bridged. Mocap samples whose innovation is implausible (marker swaps) are
rejected by a chi-square gate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.model.types import ImuSamples, MocapPoses, NoiseModel
from mocap_calib.core.policy import gap_threshold
from mocap_calib.errors import InputError

Array = NDArray[np.float64]
_I3 = np.eye(3)


@dataclass(frozen=True)
class GroundTruthCalibration:
    """The calibration the ground truth is built with (SI units, frames of the conventions).

    ``gyro_bias``/``accel_bias`` are the session means; ``*_rate`` the drift trends about
    ``t_mid_s`` (IMU-clock seconds since the IMU's time origin).
    """

    R_MI: Array
    p_MI: Array
    gravity_dir: Array
    gravity: float
    time_offset: float
    gyro_bias: Array
    accel_bias: Array
    gyro_matrix: Array = field(default_factory=lambda: np.eye(3))
    g_sensitivity: Array = field(default_factory=lambda: np.zeros((3, 3)))
    accel_matrix: Array = field(default_factory=lambda: np.eye(3))
    gyro_bias_rate: Array = field(default_factory=lambda: np.zeros(3))
    accel_bias_rate: Array = field(default_factory=lambda: np.zeros(3))
    t_mid_s: float | None = None
    sigma_gyro_bias: Array = field(default_factory=lambda: np.full(3, 1e-3))
    sigma_accel_bias: Array = field(default_factory=lambda: np.full(3, 2e-2))


@dataclass(frozen=True)
class GroundTruthOptions:
    """Output times and the limits beyond which a sample is not trusted.

    Attributes:
        rate_hz: output rate on the IMU clock (None: at the IMU stamps).
        max_position_sigma: leave out samples whose smoothed position 1-sigma exceeds this (m).
        max_rotation_sigma_deg: the same for the attitude (deg).
        gap_factor: a mocap step longer than this many median steps is a gap (reported).
        gate_chi2: reject mocap samples whose 6-dof innovation chi-square exceeds this.
    """

    rate_hz: float | None = None
    max_position_sigma: float = 2e-3
    max_rotation_sigma_deg: float = 0.1
    gap_factor: float = 1.5
    gate_chi2: float = 40.0


@dataclass
class GroundTruth:
    """IMU states at ``t_ns`` (IMU clock): only the trusted samples.

    Attributes:
        t_ns: (N,) integer stamps on the IMU clock.
        position, quat_wxyz, velocity: ``T_GI`` and ``v_GI`` in the gravity-aligned world ``G``.
        gyro_bias, accel_bias: raw-sensor biases (rad/s, m/s^2) at each sample.
        sigma_position (m), sigma_rotation_deg: smoothed 1-sigma (norm over the axes).
        R_GW: rotation of the mocap world into ``G``.
        report: how it was made (plain data for the sidecar file).
    """

    t_ns: NDArray[np.int64]
    position: Array
    quat_wxyz: Array
    velocity: Array
    gyro_bias: Array
    accel_bias: Array
    sigma_position: Array
    sigma_rotation_deg: Array
    R_GW: Array
    report: dict[str, Any]


def _exp(phi: Array) -> Array:
    """Rodrigues for one vector (faster than the vectorised helper in the per-step loop)."""
    th2 = float(phi @ phi)
    K = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if th2 < 1e-16:
        return _I3 + K + 0.5 * K @ K
    th = math.sqrt(th2)
    return _I3 + (math.sin(th) / th) * K + ((1.0 - math.cos(th)) / th2) * (K @ K)


def _jr(phi: Array) -> Array:
    th2 = float(phi @ phi)
    K = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if th2 < 1e-12:
        return _I3 - 0.5 * K
    th = math.sqrt(th2)
    return _I3 - ((1.0 - math.cos(th)) / th2) * K + ((th - math.sin(th)) / (th2 * th)) * (K @ K)


def _hat(v: Array) -> Array:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclass
class _Timeline:
    """Nodes of the filter: IMU stamps, mocap samples (IMU clock) and output times."""

    t: Array  # seconds on the IMU clock, since the IMU's time origin
    mocap: NDArray[np.int64]  # mocap index per node, -1 if none
    output: NDArray[np.bool_]


def _timeline(u: Array, tau: Array, out_t: Array) -> _Timeline:
    # Round to the nanosecond so that equal instants merge into one node.
    keys = np.round(np.concatenate([u, tau, out_t]) * 1e9).astype(np.int64)
    t_ns, inv = np.unique(keys, return_inverse=True)
    mocap = np.full(len(t_ns), -1, dtype=np.int64)
    mocap[inv[len(u):len(u) + len(tau)]] = np.arange(len(tau))
    output = np.zeros(len(t_ns), dtype=bool)
    output[inv[len(u) + len(tau):]] = True
    return _Timeline(t_ns * 1e-9, mocap, output)


def _measurements(cal: GroundTruthCalibration, mocap: MocapPoses, R_GW: Array
                  ) -> tuple[Array, Array]:
    """``R_GI`` and ``p_GI`` implied by each mocap sample."""
    R_WM = mocap.rotation
    R_GI = R_GW @ R_WM @ cal.R_MI
    p_GI = (mocap.position + np.einsum("nij,j->ni", R_WM, cal.p_MI)) @ R_GW.T
    return R_GI, p_GI


def _corrected(cal: GroundTruthCalibration, imu: ImuSamples) -> tuple[Array, Array, Array, Array]:
    """True-signal estimates with the calibrated intrinsics and mean biases (plus trends);
    also the raw-domain bias each sample was corrected with."""
    t_mid = cal.t_mid_s if cal.t_mid_s is not None else 0.5 * (imu.t[0] + imu.t[-1])
    du = (imu.t - t_mid)[:, None]
    b_g = cal.gyro_bias + du * cal.gyro_bias_rate
    b_a = cal.accel_bias + du * cal.accel_bias_rate
    f = (imu.accel - b_a) @ np.linalg.inv(cal.accel_matrix).T
    w = (imu.gyro - b_g - f @ cal.g_sensitivity.T) @ np.linalg.inv(cal.gyro_matrix).T
    return w, f, b_g, b_a


class _Filter:
    """Error-state filter over the nodes; keeps what the smoother needs."""

    def __init__(self, n: int, noise: NoiseModel, g: float) -> None:
        self.R = np.empty((n, 3, 3))
        self.x = np.empty((n, 12))  # p, v, b_g, b_a (corrected domain for the biases)
        self.P = np.empty((n, 15, 15), dtype=np.float32)
        self.Pbar = np.empty((n, 15, 15), dtype=np.float32)  # prior at node k (before update)
        self.C = np.empty((n, 15, 15))  # smoother gain from node k to k+1
        self.delta = np.zeros((n, 15))  # correction applied at node k
        self.g = np.array([0.0, 0.0, -g])
        q = np.zeros(15)
        q[0:3] = noise.gyroscope_noise_density ** 2
        q[6:9] = noise.accelerometer_noise_density ** 2
        q[9:12] = noise.gyroscope_random_walk ** 2
        q[12:15] = noise.accelerometer_random_walk ** 2
        self.q = q

    def step(self, R: Array, x: Array, P: Array, w: Array, f: Array, dt: float,
             unknown: Array | None = None) -> tuple[Array, Array, Array, Array]:
        """Propagate over ``dt`` with the (bias-corrected) rate and specific force;
        ``unknown`` (6,): the 1-sigma of rate and specific force where the IMU has a gap (the
        signal is interpolated across it)."""
        p, v, bg, ba = x[0:3], x[3:6], x[6:9], x[9:12]
        w = w - bg
        f = f - ba
        phi = w * dt
        dR = _exp(phi)
        R_mid = R @ _exp(0.5 * phi)
        a = R_mid @ f + self.g
        R1 = R @ dR
        x1 = np.concatenate([p + v * dt + 0.5 * a * dt * dt, v + a * dt, bg, ba])
        F = np.eye(15)
        Rf = R_mid @ _hat(f)
        F[0:3, 0:3] = dR.T
        F[0:3, 9:12] = -_jr(phi) * dt
        F[3:6, 0:3] = -0.5 * Rf * dt * dt
        F[3:6, 6:9] = _I3 * dt
        F[3:6, 12:15] = -0.5 * R_mid * dt * dt
        F[6:9, 0:3] = -Rf * dt
        F[6:9, 12:15] = -R_mid * dt
        Q = np.diag(self.q * dt)
        Q[3:6, 3:6] = np.diag(self.q[6:9]) * dt ** 3 / 3.0
        if unknown is not None:  # an unknown rate / force held over the step
            sw2, sf2 = unknown[0:3] ** 2 * dt**2, unknown[3:6] ** 2
            Q[0:3, 0:3] += np.diag(sw2)
            Q[3:6, 3:6] += np.diag(sf2 * dt**4 / 4.0)
            Q[6:9, 6:9] += np.diag(sf2 * dt**2)
        return R1, x1, F @ P @ F.T + Q, F


def _meas_noise(noise: NoiseModel, R_GI_meas: Array, cal: GroundTruthCalibration) -> Array:
    """Covariance of (rotation residual in I, position residual in G) of one mocap sample."""
    sr2, sp2 = noise.mocap_rotation_sigma ** 2, noise.mocap_position_sigma ** 2
    R_GM = R_GI_meas @ cal.R_MI.T
    J = -R_GM @ _hat(cal.p_MI) @ cal.R_MI
    Rm = np.zeros((6, 6))
    Rm[0:3, 0:3] = sr2 * _I3
    Rm[3:6, 0:3] = sr2 * J
    Rm[0:3, 3:6] = sr2 * J.T
    Rm[3:6, 3:6] = sp2 * _I3 + sr2 * J @ J.T
    return Rm


def _initial(cal: GroundTruthCalibration, Rm: Array, pm: Array, tau: Array, noise: NoiseModel,
             duration: float) -> tuple[Array, Array, Array]:
    """State and covariance at the first mocap sample (velocity from a local fit)."""
    k = min(len(tau) - 1, 4)
    v = np.polyfit(tau[:k + 1] - tau[0], pm[:k + 1], 1)[0] if k >= 1 else np.zeros(3)
    x = np.concatenate([pm[0], v, np.zeros(6)])
    sb_g = np.sqrt(cal.sigma_gyro_bias ** 2 + noise.gyroscope_random_walk ** 2 * duration)
    sb_a = np.sqrt(cal.sigma_accel_bias ** 2 + noise.accelerometer_random_walk ** 2 * duration)
    P = np.diag(np.concatenate([np.full(3, noise.mocap_rotation_sigma ** 2),
                                np.full(3, noise.mocap_position_sigma ** 2),
                                np.full(3, 0.05 ** 2), sb_g ** 2, sb_a ** 2]))
    return Rm[0].copy(), x, P


def _forward(tl: _Timeline, imu_t: Array, w: Array, f: Array, Rm: Array, pm: Array,
             cal: GroundTruthCalibration, noise: NoiseModel, gate: float
             ) -> tuple[_Filter, NDArray[np.bool_]]:
    n = len(tl.t)
    flt = _Filter(n, noise, cal.gravity)
    first = int(np.flatnonzero(tl.mocap >= 0)[0])
    tau = tl.t[tl.mocap >= 0]
    R, x, P = _initial(cal, Rm, pm, tau, noise, imu_t[-1] - imu_t[0])
    accepted = np.zeros(len(Rm), dtype=bool)
    accepted[0] = True
    flt.R[first], flt.x[first], flt.P[first], flt.Pbar[first] = R, x, P, P
    # IMU sample intervals: node k..k+1 uses the IMU signal linearly interpolated at the middle.
    mid = 0.5 * (tl.t[:-1] + tl.t[1:])
    j = np.clip(np.searchsorted(imu_t, mid) - 1, 0, len(imu_t) - 2)
    a = np.clip((mid - imu_t[j]) / (imu_t[j + 1] - imu_t[j]), 0.0, 1.0)[:, None]
    w_mid = (1 - a) * w[j] + a * w[j + 1]
    f_mid = (1 - a) * f[j] + a * f[j + 1]
    # Across an IMU gap the signal is only interpolated: its uncertainty is the signal's own
    # spread (the IMU bridges short gaps; over long ones the mocap carries the state).
    in_gap = (imu_t[j + 1] - imu_t[j]) > gap_threshold(imu_t)
    unknown = np.concatenate([np.std(w, axis=0), np.std(f, axis=0)])
    H = np.zeros((6, 15))
    H[0:3, 0:3] = _I3
    H[3:6, 3:6] = _I3
    for k in range(first, n - 1):
        R1, x1, P1, F = flt.step(R, x, P, w_mid[k], f_mid[k], tl.t[k + 1] - tl.t[k],
                                 unknown if in_gap[k] else None)
        flt.Pbar[k + 1] = P1
        flt.C[k] = np.linalg.solve(P1, F @ P).T  # P F^T P1^-1 (P1 symmetric)
        m = tl.mocap[k + 1]
        if m >= 0:
            nu = np.concatenate([so3.log(R1.T @ Rm[m]), pm[m] - x1[0:3]])
            S = H @ P1 @ H.T + _meas_noise(noise, Rm[m], cal)
            K = np.linalg.solve(S, H @ P1).T
            if float(nu @ np.linalg.solve(S, nu)) < gate:
                d = K @ nu
                R1 = R1 @ _exp(d[0:3])
                x1 = x1 + d[3:]
                IKH = np.eye(15) - K @ H
                P1 = IKH @ P1 @ IKH.T + K @ _meas_noise(noise, Rm[m], cal) @ K.T
                flt.delta[k + 1] = d
                accepted[m] = True
        R, x, P = R1, x1, 0.5 * (P1 + P1.T)
        flt.R[k + 1], flt.x[k + 1], flt.P[k + 1] = R, x, P
    flt.first = first  # type: ignore[attr-defined]
    return flt, accepted


def _smooth(flt: _Filter) -> tuple[Array, Array]:
    """RTS in error form: e_k = C_k (e_{k+1} + delta_{k+1}); returns errors and covariances'
    position and attitude variances (sum over the axes)."""
    n = len(flt.R)
    first = flt.first  # type: ignore[attr-defined]
    e = np.zeros((n, 15))
    var = np.zeros((n, 2))
    Ps = flt.P[-1].astype(float)
    var[-1] = [np.trace(Ps[3:6, 3:6]), np.trace(Ps[0:3, 0:3])]
    for k in range(n - 2, first - 1, -1):
        C = flt.C[k]
        e[k] = C @ (e[k + 1] + flt.delta[k + 1])
        Ps = flt.P[k] + C @ (Ps - flt.Pbar[k + 1]) @ C.T
        var[k] = [np.trace(Ps[3:6, 3:6]), np.trace(Ps[0:3, 0:3])]
    return e, var


def _gaps(tau: Array, factor: float) -> list[tuple[float, float]]:
    d = np.diff(tau)
    if len(d) == 0:
        return []
    big = np.flatnonzero(d > factor * np.median(d))
    return [(float(tau[i]), float(d[i])) for i in big]


def ground_truth(imu: ImuSamples, mocap: MocapPoses, cal: GroundTruthCalibration,
                 noise: NoiseModel, opts: GroundTruthOptions | None = None) -> GroundTruth:
    """Smoothed IMU states on the IMU clock (see the module docstring).

    Raises:
        InputError: the mocap (shifted by the clock offset) does not overlap the IMU.
    """
    opts = opts or GroundTruthOptions()
    R_GW = so3.rotation_between(cal.gravity_dir, [0.0, 0.0, -1.0])
    # Mocap sample times on the IMU clock (integer ns difference first: epochs are large).
    tau = ((mocap.stamps_ns() - imu.time_origin_ns) * 1e-9) - cal.time_offset
    inside = (tau > imu.t[0]) & (tau < imu.t[-1])
    if inside.sum() < 2:
        raise InputError("the mocap, shifted by the calibration's time offset "
                         f"({cal.time_offset:.6g} s), does not overlap the IMU; check that the "
                         "calibration belongs to this session")
    tau = tau[inside]
    Rm, pm = _measurements(cal, mocap.select(inside), R_GW)
    if opts.rate_hz is not None:
        if not opts.rate_hz > 0:
            raise InputError(f"--rate {opts.rate_hz}: must be positive")
        out_t = np.arange(math.ceil(tau[0] * opts.rate_hz), math.floor(tau[-1] * opts.rate_hz)
                          + 1) / opts.rate_hz
    else:
        out_t = imu.t[(imu.t >= tau[0]) & (imu.t <= tau[-1])]
    tl = _timeline(imu.t[(imu.t >= tau[0]) & (imu.t <= tau[-1])], tau, out_t)
    w, f, b_g0, b_a0 = _corrected(cal, imu)
    flt, accepted = _forward(tl, imu.t, w, f, Rm, pm, cal, noise, opts.gate_chi2)
    e, var = _smooth(flt)
    return _assemble(imu, tl, flt, e, var, (b_g0, b_a0), cal, opts, R_GW, tau, accepted)


def _assemble(imu: ImuSamples, tl: _Timeline, flt: _Filter, e: Array, var: Array,
              biases: tuple[Array, Array], cal: GroundTruthCalibration,
              opts: GroundTruthOptions, R_GW: Array, tau: Array,
              accepted: NDArray[np.bool_]) -> GroundTruth:
    idx = np.flatnonzero(tl.output)
    R = flt.R[idx] @ so3.exp(e[idx, 0:3])
    x = flt.x[idx] + e[idx, 3:15]
    sig_p = np.sqrt(np.maximum(var[idx, 0], 0))
    sig_r = np.degrees(np.sqrt(np.maximum(var[idx, 1], 0)))
    trusted = (sig_p <= opts.max_position_sigma) & (sig_r <= opts.max_rotation_sigma_deg)
    t = tl.t[idx]
    # Raw-domain biases: w_m = M_g (w + db_g) + G (f + db_a) + b_g0, a_m = M_a (f + db_a) + b_a0.
    b_g0 = np.stack([np.interp(t, imu.t, biases[0][:, i]) for i in range(3)], axis=1)
    b_a0 = np.stack([np.interp(t, imu.t, biases[1][:, i]) for i in range(3)], axis=1)
    gyro_b = b_g0 + x[:, 6:9] @ cal.gyro_matrix.T + x[:, 9:12] @ cal.g_sensitivity.T
    accel_b = b_a0 + x[:, 9:12] @ cal.accel_matrix.T
    t_ns = imu.time_origin_ns + np.round(t * 1e9).astype(np.int64)
    gaps = _gaps(tau[accepted], opts.gap_factor)
    report = _report(t, trusted, gaps, tau, accepted, opts, R_GW, sig_p, sig_r)
    d = np.diff(imu.t)
    report["imu_gaps"] = [{"start_s": round(float(imu.t[i]), 6), "length_s": round(float(d[i]), 6)}
                          for i in np.flatnonzero(d > gap_threshold(imu.t))]
    keep = trusted
    return GroundTruth(t_ns[keep], x[keep, 0:3], so3.rotmat_to_quat(R[keep]), x[keep, 3:6],
                       gyro_b[keep], accel_b[keep], sig_p[keep], sig_r[keep], R_GW, report)


def _spans(t: Array, mask: NDArray[np.bool_]) -> list[list[float]]:
    """[start, end] (IMU-clock s) of the runs where ``mask`` is True."""
    if not mask.any():
        return []
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    starts = np.flatnonzero(np.diff(m) == 1)
    ends = np.flatnonzero(np.diff(m) == -1) - 1
    return [[round(float(t[a]), 6), round(float(t[b]), 6)] for a, b in zip(starts, ends,
                                                                        strict=True)]


def _report(t: Array, trusted: NDArray[np.bool_], gaps: list[tuple[float, float]], tau: Array,
            accepted: NDArray[np.bool_], opts: GroundTruthOptions, R_GW: Array, sig_p: Array,
            sig_r: Array) -> dict[str, Any]:
    gap_rows = []
    for start, length in gaps:
        inside = (t > start) & (t < start + length)
        gap_rows.append({"start_s": round(start, 6), "length_s": round(length, 6),
                         "bridged": bool(trusted[inside].all()) if inside.any() else True})
    return {
        "method": "error-state Kalman filter and RTS smoother: IMU (calibrated intrinsics, "
                  "random-walk biases) between mocap poses mapped through T_MI, gravity tilt "
                  "and clock offset",
        "world": "gravity-aligned: z up, the mocap world's yaw (R_GW = smallest rotation "
                 "taking g_W to -z)",
        "R_GW": R_GW.tolist(),
        "clock": "IMU clock (stamps of the IMU log)",
        "samples_written": int(trusted.sum()),
        "samples_left_out": int((~trusted).sum()),
        "spans_left_out_s": _spans(t, ~trusted),
        "mocap_samples_used": int(accepted.sum()),
        "mocap_samples_rejected": int((~accepted).sum()),
        "mocap_gaps": gap_rows,
        "limits": {"max_position_sigma_m": opts.max_position_sigma,
                   "max_rotation_sigma_deg": opts.max_rotation_sigma_deg},
        "sigma_position_m": {"median": float(np.median(sig_p)), "max_written":
                             float(sig_p[trusted].max()) if trusted.any() else None},
        "sigma_rotation_deg": {"median": float(np.median(sig_r)), "max_written":
                               float(sig_r[trusted].max()) if trusted.any() else None},
    }
