"""Vectorised SO(3) helpers on numpy arrays of shape (..., 3) and (..., 3, 3).

Conventions: Hamilton quaternions stored ``[w, x, y, z]``; ``exp``/``log`` are the rotation-vector
maps; ``right_jacobian(phi)`` satisfies ``exp(phi + d) ~= exp(phi) exp(Jr(phi) d)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.threads import map_blocks

Array = NDArray[np.float64]

_SMALL = 1e-8
#: Rotations per block of :func:`log` on the threads (more than two blocks' worth are split).
LOG_BLOCK = 32768
#: From this many rotations :func:`log` runs compiled (one pass instead of numpy's temporaries;
#: fewer stay in numpy, so that a command that logs a few rotations does not load numba).
COMPILED_LOG = 256


def hat(v: Array) -> Array:
    """Skew-symmetric matrices ``[v]x`` of shape (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def _coeffs(theta2: Array) -> tuple[Array, Array, Array]:
    """``sin(t)/t``, ``(1-cos t)/t^2``, ``(t - sin t)/t^3`` with Taylor series near zero."""
    small = theta2 < _SMALL
    t2 = np.where(small, 1.0, theta2)
    t = np.sqrt(t2)
    a = np.where(small, 1.0 - theta2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(t)) / t2)
    c = np.where(small, 1.0 / 6.0 - theta2 / 120.0, (t - np.sin(t)) / (t2 * t))
    return a, b, c


def exp(phi: Array) -> Array:
    """Rotation matrices ``Exp(phi)`` (Rodrigues)."""
    phi = np.asarray(phi, dtype=float)
    theta2 = np.einsum("...i,...i->...", phi, phi)
    a, b, _ = _coeffs(theta2)
    K = hat(phi)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + a[..., None, None] * K + b[..., None, None] * (K @ K)


def log(R: Array) -> Array:
    """Rotation vectors ``Log(R)``, robust near 0 and pi (many compiled, a session's worth in
    blocks on the threads: each rotation on its own, so the same numbers)."""
    R = np.asarray(R, dtype=float)
    n = R.size // 9
    if n < COMPILED_LOG:
        return quat_to_rotvec(rotmat_to_quat(R))
    from mocap_calib.core.model.so3_compiled import log_kernel

    flat = np.ascontiguousarray(R.reshape(n, 3, 3))
    out = np.empty((n, 3))
    if n < 2 * LOG_BLOCK:
        log_kernel(flat, out)
        return out.reshape(R.shape[:-2] + (3,))

    def block(a: int) -> None:
        log_kernel(flat[a:a + LOG_BLOCK], out[a:a + LOG_BLOCK])

    map_blocks(block, range(0, n, LOG_BLOCK))
    return out.reshape(R.shape[:-2] + (3,))


def right_jacobian(phi: Array) -> Array:
    """Right Jacobian of SO(3): ``Jr = I - b K + c K^2``."""
    phi = np.asarray(phi, dtype=float)
    theta2 = np.einsum("...i,...i->...", phi, phi)
    _, b, c = _coeffs(theta2)
    K = hat(phi)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye - b[..., None, None] * K + c[..., None, None] * (K @ K)


def right_jacobian_inv(phi: Array) -> Array:
    """Inverse right Jacobian of SO(3)."""
    phi = np.asarray(phi, dtype=float)
    theta2 = np.einsum("...i,...i->...", phi, phi)
    small = theta2 < _SMALL
    t2 = np.where(small, 1.0, theta2)
    t = np.sqrt(t2)
    d = np.where(
        small,
        1.0 / 12.0 + theta2 / 720.0,
        1.0 / t2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(np.where(small, 1.0, t))),
    )
    K = hat(phi)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + 0.5 * K + d[..., None, None] * (K @ K)


def quat_to_rotmat(q_wxyz: Array) -> Array:
    """Rotation matrices from Hamilton quaternions ``[w, x, y, z]`` (normalised first)."""
    q = np.asarray(q_wxyz, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def rotmat_to_quat(R: Array) -> Array:
    """Hamilton quaternions ``[w, x, y, z]`` with ``w >= 0`` (Shepperd's method)."""
    R = np.asarray(R, dtype=float)
    m = R.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    diag = np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    cand = np.concatenate([tr[:, None], diag], axis=1)
    k = np.argmax(cand, axis=1)
    q = np.empty((m.shape[0], 4))
    for case in range(4):
        sel = k == case
        if not np.any(sel):
            continue
        r = m[sel]
        if case == 0:
            s = np.sqrt(1.0 + tr[sel]) * 2.0
            q[sel] = np.stack(
                [0.25 * s, (r[:, 2, 1] - r[:, 1, 2]) / s, (r[:, 0, 2] - r[:, 2, 0]) / s,
                 (r[:, 1, 0] - r[:, 0, 1]) / s], axis=1)
        elif case == 1:
            s = np.sqrt(1.0 + r[:, 0, 0] - r[:, 1, 1] - r[:, 2, 2]) * 2.0
            q[sel] = np.stack(
                [(r[:, 2, 1] - r[:, 1, 2]) / s, 0.25 * s, (r[:, 0, 1] + r[:, 1, 0]) / s,
                 (r[:, 0, 2] + r[:, 2, 0]) / s], axis=1)
        elif case == 2:
            s = np.sqrt(1.0 + r[:, 1, 1] - r[:, 0, 0] - r[:, 2, 2]) * 2.0
            q[sel] = np.stack(
                [(r[:, 0, 2] - r[:, 2, 0]) / s, (r[:, 0, 1] + r[:, 1, 0]) / s, 0.25 * s,
                 (r[:, 1, 2] + r[:, 2, 1]) / s], axis=1)
        else:
            s = np.sqrt(1.0 + r[:, 2, 2] - r[:, 0, 0] - r[:, 1, 1]) * 2.0
            q[sel] = np.stack(
                [(r[:, 1, 0] - r[:, 0, 1]) / s, (r[:, 0, 2] + r[:, 2, 0]) / s,
                 (r[:, 1, 2] + r[:, 2, 1]) / s, 0.25 * s], axis=1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1.0
    return q.reshape(R.shape[:-2] + (4,))


def quat_to_rotvec(q_wxyz: Array) -> Array:
    """Rotation vectors from quaternions, angle in [0, pi]."""
    q = np.asarray(q_wxyz, dtype=float)
    q = np.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    w = np.clip(q[..., 0], -1.0, 1.0)
    angle = 2.0 * np.arctan2(s, w)
    small = s < 1e-12
    scale = np.where(small, 2.0 / np.where(w == 0, 1.0, w), angle / np.where(small, 1.0, s))
    return v * scale[..., None]


def quat_multiply(a: Array, b: Array) -> Array:
    """Hamilton product ``a * b`` of ``[w, x, y, z]`` quaternions."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [aw * bw - ax * bx - ay * by - az * bz,
         aw * bx + ax * bw + ay * bz - az * by,
         aw * by - ax * bz + ay * bw + az * bx,
         aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def rotation_between(a: Array, b: Array) -> Array:
    """Smallest rotation ``R`` with ``R a/|a| = b/|b|`` (single vectors)."""
    a = np.asarray(a, dtype=float) / np.linalg.norm(a)
    b = np.asarray(b, dtype=float) / np.linalg.norm(b)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis)
    c = float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(perp) < 1e-6:
            perp = np.cross(a, [0.0, 1.0, 0.0])
        return exp(np.pi * perp / np.linalg.norm(perp))
    return exp(axis / s * np.arctan2(s, c))


def angle_deg(R: Array) -> Array:
    """Rotation angle of ``R`` in degrees."""
    return np.degrees(np.linalg.norm(log(R), axis=-1))


def tilt_basis(g_dir: Array) -> Array:
    """Two unit vectors orthogonal to ``g_dir`` (columns of a 3x2 matrix), the tangent basis
    in which the gravity direction's 2-DoF error ``delta`` acts: ``g' = exp(B delta) g``."""
    g = np.asarray(g_dir, dtype=float) / np.linalg.norm(g_dir)
    helper = np.array([1.0, 0.0, 0.0]) if abs(g[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    b1 = np.cross(g, helper)
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(g, b1)
    return np.stack([b1, b2], axis=1)
