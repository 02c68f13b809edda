"""IMU dead reckoning from the mocap state, before and after calibration (for inspection).

Short segments are integrated from the mocap pose with the same integration as the window
engine, once from the raw IMU and once through the calibrated model; their drift against the
mocap shows what the calibration bought.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.model.imu_model import Intrinsics, correct, imu_times
from mocap_calib.core.model.preint import compose, integrate_pieces, pieces
from mocap_calib.core.prepare.session import PreparedSession, local_derivative
from mocap_calib.core.result.state import ModelState

Array = NDArray[np.float64]

#: Length (s) of one dead-reckoning segment, and spacing (s) of their starts.
DR_LENGTH_S = 2.0
DR_EVERY_S = 10.0


@dataclass(frozen=True)
class DeadReckoning:
    """IMU dead-reckoning segments started from the mocap state.

    Attributes:
        tau: (S, m+1) mocap times of the segment samples.
        R_ref, p_ref: (S, m+1, 3, 3), (S, m+1, 3) IMU pose from the mocap (``T_WM T_MI``).
        R_before, p_before: integrated from the raw IMU (zero biases, no effects).
        R_after, p_after: integrated through the calibrated model (knot biases, effects).
    """

    tau: Array
    R_ref: Array
    p_ref: Array
    R_before: Array
    p_before: Array
    R_after: Array
    p_after: Array

    def position_error(self, which: str) -> Array:
        """(S,) position error at the segment ends (m), ``which`` = before / after."""
        p = self.p_before if which == "before" else self.p_after
        return np.linalg.norm(p[:, -1] - self.p_ref[:, -1], axis=1)

    def attitude_error(self, which: str) -> Array:
        """(S,) attitude error at the segment ends (deg)."""
        R = self.R_before if which == "before" else self.R_after
        return so3.angle_deg(np.einsum("sji,sjk->sik", R[:, -1], self.R_ref[:, -1]))


def dead_reckoning(s: PreparedSession, st: ModelState, length: float = DR_LENGTH_S,
                   every: float = DR_EVERY_S) -> DeadReckoning | None:
    """Integrate the IMU for ``length`` seconds from the mocap state, every ``every`` seconds.

    Each segment starts at a mocap sample with the IMU attitude and position ``T_WM T_MI`` and
    the IMU-origin velocity from a local quadratic fit of ``p_WI``; it is integrated with the
    core's preintegration (Hermite-interpolated IMU, RK4 between mocap samples) under the
    estimated gravity ``g_W`` and clock offset. Segments crossing a mocap gap or the IMU's ends
    are skipped.

    Returns:
        The segments, or None if the session has room for none.
    """
    M = len(s.tau)
    m = max(2, int(round(length * s.mocap_rate)))
    if M <= m + 1:
        return None
    R_WI = s.R_WM @ st.R_MI
    p_WI = s.p_WM + s.R_WM @ st.p_MI
    half = max(2, int(round(0.05 * s.mocap_rate)))
    _, v_WI, valid = local_derivative(s.tau, p_WI, half, s.gap)
    cand = np.searchsorted(s.tau, np.arange(s.tau[0] + 0.5 * every, s.tau[-1] - length, every))
    cand = np.unique(cand[cand + m < M])
    if len(cand) == 0:
        return None
    ok = (valid[cand] & s.segments_without_gaps(cand, cand + m)
          & s.imu_covers(s.tau[cand], s.tau[cand + m], st.delta))
    i0 = cand[ok]
    if len(i0) == 0:
        return None
    idx = i0[:, None] + np.arange(m + 1)
    tau = s.tau[idx]
    h = np.diff(tau, axis=1)
    ut = imu_times(st.model, Intrinsics(np.zeros(3), np.zeros(3), st.effects, st.t_mid), s.u)
    pc = pieces(ut, tau[:, :-1], tau[:, 1:], st.delta)  # the window engine's integration
    nodes = pc.nodes
    u_nodes = nodes - st.delta
    gyro, accel = pc(s.gyro), pc(s.accel)
    b = st.bias_at(nodes.ravel()).reshape(nodes.shape + (6,))
    corr = correct(st.model, Intrinsics(b[..., 0:3], b[..., 3:6], st.effects, st.t_mid),
                   gyro, accel, u_nodes, sensitivities=False)
    start = (R_WI[i0], p_WI[i0], v_WI[i0])
    R_b, p_b, _ = compose(integrate_pieces(gyro, accel, pc.hs), h, *start, st.g_W)
    R_a, p_a, _ = compose(integrate_pieces(corr.w, corr.f, pc.hs), h, *start, st.g_W)
    return DeadReckoning(tau, R_WI[idx], p_WI[idx], R_b, p_b, R_a, p_a)
