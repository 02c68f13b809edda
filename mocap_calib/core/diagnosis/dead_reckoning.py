"""IMU dead reckoning from the mocap state, before and after calibration (for inspection).

Short segments are integrated from the mocap pose with the same integration as the window
engine, once from the raw IMU and once through the calibrated model; their drift against the
mocap shows what the calibration bought.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.imu_model import Intrinsics, correct, imu_times
from mocap_calib.core.model.preint import compose, integrate_pieces, pieces
from mocap_calib.core.prepare.session import PreparedSession, local_derivative
from mocap_calib.core.result.series import DeadReckoning
from mocap_calib.core.result.state import ModelState

Array = NDArray[np.float64]

#: Length (s) of one dead-reckoning segment, and spacing (s) of their starts.
DR_LENGTH_S = 2.0
DR_EVERY_S = 10.0


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
    return DeadReckoning(tau, R_WI[idx], p_WI[idx], R_b, p_b, R_a, p_a, length)
