"""SO(3) maps compiled (numba): the rotation log of many rotations in one pass, and its
per-rotation body for other kernels to inline (:func:`mocap_calib.core.model.so3.log` and the
window filter's residuals use them)."""

from __future__ import annotations

import numpy as np

from mocap_calib.core.jit import kernel

# ruff: noqa: N803  (matrix names)


@kernel
def log_kernel(R, out):  # pragma: no cover  (compiled)
    """``out[n] = Log(R[n])`` for (N, 3, 3) rotations ``R``."""
    q, v = np.zeros(4), np.zeros(3)
    m = np.zeros((3, 3))
    for n in range(R.shape[0]):
        for i in range(3):
            for j in range(3):
                m[i, j] = R[n, i, j]
        rot_log(m, q, v)
        for i in range(3):
            out[n, i] = v[i]


@kernel(inline=True)
def rot_log(m, q, v):  # pragma: no cover  (compiled)
    """``v = Log(m)`` (``q``: work space): Shepperd's quaternion (``w >= 0``), then its rotation
    vector (as :func:`~mocap_calib.core.model.so3.rotmat_to_quat` and ``quat_to_rotvec``)."""
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    case, best = 0, tr
    for i in range(3):
        if m[i, i] > best:
            case, best = i + 1, m[i, i]
    if case == 0:
        s = np.sqrt(1.0 + tr) * 2.0
        q[0], q[1], q[2], q[3] = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s,
                                  (m[1, 0] - m[0, 1]) / s)
    elif case == 1:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2.0
        q[0], q[1], q[2], q[3] = ((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s,
                                  (m[0, 2] + m[2, 0]) / s)
    elif case == 2:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2.0
        q[0], q[1], q[2], q[3] = ((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s,
                                  (m[1, 2] + m[2, 1]) / s)
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2.0
        q[0], q[1], q[2], q[3] = ((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s,
                                  (m[1, 2] + m[2, 1]) / s, 0.25 * s)
    n = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    sign = -1.0 if q[0] / n < 0.0 else 1.0
    for i in range(4):
        q[i] = sign * (q[i] / n)
    sv = np.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    c = min(max(q[0], -1.0), 1.0)
    if sv < 1e-12:
        scale = 2.0 / (1.0 if c == 0.0 else c)
    else:
        scale = 2.0 * np.arctan2(sv, c) / sv
    for i in range(3):
        v[i] = q[1 + i] * scale
