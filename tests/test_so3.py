"""SO(3) helpers against independent references: scipy's Rotation (scalar-last quaternions),
the matrix exponential of the skew matrix, and numerical derivatives."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from mocap_calib.core.model import so3


def skew(v: np.ndarray) -> np.ndarray:
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def ref_exp(phi: np.ndarray) -> np.ndarray:
    return expm(skew(np.asarray(phi, dtype=float)))


def ref_log(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(R).as_rotvec()


def ref_quat_wxyz(R: np.ndarray) -> np.ndarray:
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


def ref_matrix_from_wxyz(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def random_unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def sample_rotvecs(seed: int = 0) -> list[np.ndarray]:
    """Rotation vectors spanning zero, the Taylor branch (|phi| < 1e-4), moderate angles and
    angles just below pi."""
    rng = np.random.default_rng(seed)
    out = [np.zeros(3)]
    for angle in (1e-12, 1e-9, 3e-5, 9.9e-5, 1.01e-4, 1e-3, 0.1, 0.7, 1.5, 2.5, 3.0,
                  np.pi - 1e-3, np.pi - 1e-6, np.pi - 1e-9):
        out.append(angle * random_unit(rng))
    out.extend(rng.uniform(-1.7, 1.7, size=(6, 3)))
    return out


ROTVECS = sample_rotvecs()


def test_hat_is_cross_product() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, 5, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", so3.hat(a), b), np.cross(a, b),
                               rtol=0, atol=1e-14)


@pytest.mark.parametrize("phi", ROTVECS, ids=lambda p: f"{np.linalg.norm(p):.3g}")
def test_exp_matches_matrix_exponential(phi: np.ndarray) -> None:
    R = so3.exp(phi)
    np.testing.assert_allclose(R, ref_exp(phi), rtol=0, atol=1e-14)
    np.testing.assert_allclose(R @ R.T, np.eye(3), rtol=0, atol=1e-14)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)


def test_exp_log_vectorised_shapes() -> None:
    rng = np.random.default_rng(2)
    phi = rng.uniform(-1.5, 1.5, size=(4, 5, 3))
    R = so3.exp(phi)
    assert R.shape == (4, 5, 3, 3)
    for idx in np.ndindex(4, 5):
        np.testing.assert_allclose(R[idx], ref_exp(phi[idx]), rtol=0, atol=1e-14)
    np.testing.assert_allclose(so3.log(R), phi, rtol=0, atol=1e-13)


@pytest.mark.parametrize("phi", ROTVECS, ids=lambda p: f"{np.linalg.norm(p):.3g}")
def test_log_inverts_exp(phi: np.ndarray) -> None:
    """For angles below pi the rotation vector is unique, so log(exp(phi)) == phi; near zero
    the relative precision must survive (no 1 - cos cancellation)."""
    R = ref_exp(phi)
    got = so3.log(R)
    theta = np.linalg.norm(phi)
    # Near pi the rotation axis is ill-conditioned in the matrix (error ~ eps / (pi - theta)).
    atol = 1e-12 if theta < 3.0 else 1e-15 / (np.pi - theta) + 1e-12
    np.testing.assert_allclose(got, phi, rtol=1e-9, atol=atol)
    np.testing.assert_allclose(got, ref_log(R), rtol=1e-9, atol=atol)
    assert np.linalg.norm(got) <= np.pi + 1e-12


def test_log_exactly_pi_and_over_pi() -> None:
    """At pi either sign of the axis is right; above pi log returns the short way round."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        axis = random_unit(rng)
        R = ref_exp(np.pi * axis)
        got = so3.log(R)
        assert np.linalg.norm(got) == pytest.approx(np.pi, abs=1e-7)
        np.testing.assert_allclose(ref_exp(got), R, rtol=0, atol=1e-12)
        over = ref_exp((np.pi + 0.3) * axis)
        np.testing.assert_allclose(so3.log(over), -(np.pi - 0.3) * axis, rtol=0, atol=1e-12)


@pytest.mark.parametrize("phi", ROTVECS, ids=lambda p: f"{np.linalg.norm(p):.3g}")
def test_right_jacobian_is_derivative_of_exp(phi: np.ndarray) -> None:
    """``exp(phi + d) = exp(phi) exp(Jr(phi) d) + O(d^2)``: column k of Jr is the central
    difference of ``Log(exp(phi)^T exp(phi + e_k eps)) / eps``."""
    eps = 1e-6
    R0 = ref_exp(phi)
    num = np.empty((3, 3))
    for k in range(3):
        e = np.zeros(3)
        e[k] = eps
        plus = ref_log(R0.T @ ref_exp(phi + e))
        minus = ref_log(R0.T @ ref_exp(phi - e))
        num[:, k] = (plus - minus) / (2 * eps)
    np.testing.assert_allclose(so3.right_jacobian(phi), num, rtol=0, atol=1e-8)


@pytest.mark.parametrize("phi", ROTVECS, ids=lambda p: f"{np.linalg.norm(p):.3g}")
def test_right_jacobian_closed_form_and_inverse(phi: np.ndarray) -> None:
    """The textbook closed form (Chirikjian; Forster et al. 2017, eq. 8) and Jr_inv Jr = I."""
    theta = np.linalg.norm(phi)
    K = skew(phi)
    if theta > 1e-3:
        ref = (np.eye(3) - (1 - np.cos(theta)) / theta**2 * K
               + (theta - np.sin(theta)) / theta**3 * K @ K)
        np.testing.assert_allclose(so3.right_jacobian(phi), ref, rtol=0, atol=1e-13)
    Jr = so3.right_jacobian(phi)
    Jr_inv = so3.right_jacobian_inv(phi)
    # Near pi, (1 + cos t) / sin t loses ~eps / (pi - t) absolutely: allow that.
    atol = 1e-11 if theta < 3.0 else 1e-11 + 1e-15 / (np.pi - theta)
    np.testing.assert_allclose(Jr_inv @ Jr, np.eye(3), rtol=0, atol=atol)
    np.testing.assert_allclose(Jr @ Jr_inv, np.eye(3), rtol=0, atol=atol)


def test_right_jacobians_vectorised() -> None:
    rng = np.random.default_rng(4)
    phi = rng.uniform(-1.5, 1.5, size=(7, 3))
    phi[0] = 0.0
    phi[1] = 1e-6
    Jr = so3.right_jacobian(phi)
    Jr_inv = so3.right_jacobian_inv(phi)
    assert Jr.shape == Jr_inv.shape == (7, 3, 3)
    np.testing.assert_allclose(Jr_inv @ Jr, np.broadcast_to(np.eye(3), (7, 3, 3)), atol=1e-11)


@pytest.mark.parametrize("phi", ROTVECS, ids=lambda p: f"{np.linalg.norm(p):.3g}")
def test_quaternion_matrix_round_trip(phi: np.ndarray) -> None:
    R = ref_exp(phi)
    q = so3.rotmat_to_quat(R)
    assert q.shape == (4,)
    assert q[0] >= 0.0
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)
    q_ref = ref_quat_wxyz(R)
    q_ref = q_ref if q_ref[0] >= 0 else -q_ref
    if q_ref[0] < 1e-6:  # angle ~ pi: w ~ 0, both signs describe the rotation
        assert min(np.abs(q - q_ref).max(), np.abs(q + q_ref).max()) < 1e-9
    else:
        np.testing.assert_allclose(q, q_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(so3.quat_to_rotmat(q), R, rtol=0, atol=1e-14)
    # Analytic quaternion of the rotation vector (Hamilton): [cos(t/2), sin(t/2) axis].
    theta = np.linalg.norm(phi)
    if theta > 0:
        q_an = np.concatenate([[np.cos(theta / 2)], np.sin(theta / 2) * phi / theta])
        assert min(np.abs(q - q_an).max(), np.abs(q + q_an).max()) < 1e-9


def test_quat_to_rotmat_matches_scipy_and_normalises() -> None:
    rng = np.random.default_rng(5)
    q = rng.normal(size=(50, 4))  # not unit, both signs of w
    R = so3.quat_to_rotmat(q)
    for qi, Ri in zip(q, R, strict=True):
        np.testing.assert_allclose(Ri, ref_matrix_from_wxyz(qi / np.linalg.norm(qi)), atol=1e-14)
        np.testing.assert_allclose(so3.quat_to_rotmat(-qi), Ri, atol=1e-15)
    back = so3.rotmat_to_quat(R)
    assert back.shape == (50, 4)
    assert np.all(back[:, 0] >= 0)
    qn = q / np.linalg.norm(q, axis=1, keepdims=True)
    qn[qn[:, 0] < 0] *= -1
    np.testing.assert_allclose(back, qn, rtol=0, atol=1e-13)


def test_rotmat_to_quat_all_shepperd_branches() -> None:
    """Rotations by large angles about each axis make each diagonal entry the largest."""
    for axis in np.eye(3):
        for angle in (2.0, 3.0, np.pi - 1e-8, np.pi):
            R = ref_exp(angle * axis)
            q = so3.rotmat_to_quat(R)
            assert q[0] >= 0
            np.testing.assert_allclose(so3.quat_to_rotmat(q), R, atol=1e-14)
            q_an = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])
            np.testing.assert_allclose(np.abs(q), np.abs(q_an), atol=1e-12)


def test_quat_to_rotvec_angle_in_range() -> None:
    rng = np.random.default_rng(6)
    q = rng.normal(size=(100, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    v = so3.quat_to_rotvec(q)
    ang = np.linalg.norm(v, axis=1)
    assert np.all(ang <= np.pi + 1e-12)
    for qi, vi in zip(q, v, strict=True):
        np.testing.assert_allclose(ref_exp(vi), ref_matrix_from_wxyz(qi), atol=1e-13)


def test_quat_multiply_matches_matrix_product() -> None:
    rng = np.random.default_rng(7)
    a = rng.normal(size=(20, 4))
    b = rng.normal(size=(20, 4))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    ab = so3.quat_multiply(a, b)
    np.testing.assert_allclose(np.linalg.norm(ab, axis=1), 1.0, atol=1e-15)
    for ai, bi, abi in zip(a, b, ab, strict=True):
        np.testing.assert_allclose(ref_matrix_from_wxyz(abi),
                                   ref_matrix_from_wxyz(ai) @ ref_matrix_from_wxyz(bi),
                                   atol=1e-14)
        # scipy composes the same way: (A * B).apply(x) == A.apply(B.apply(x)).
        ra = Rotation.from_quat([*ai[1:], ai[0]])
        rb = Rotation.from_quat([*bi[1:], bi[0]])
        x, y, z, w = (ra * rb).as_quat()
        ref = np.array([w, x, y, z])
        assert min(np.abs(abi - ref).max(), np.abs(abi + ref).max()) < 1e-14
    # Hamilton convention: i * j = k.
    i, j, k = np.eye(4)[1:]
    np.testing.assert_allclose(so3.quat_multiply(i, j), k)


def test_rotation_between() -> None:
    rng = np.random.default_rng(8)
    for _ in range(10):
        a, b = rng.normal(size=(2, 3))
        R = so3.rotation_between(a, b)
        np.testing.assert_allclose(R @ a / np.linalg.norm(a), b / np.linalg.norm(b), atol=1e-14)
        # The smallest rotation: its axis is perpendicular to both vectors.
        axis = ref_log(R)
        assert abs(axis @ a) < 1e-12 * np.linalg.norm(a)
        assert abs(axis @ b) < 1e-12 * np.linalg.norm(b)
    for a in (np.array([1.0, 0, 0]), np.array([0.0, 0.3, -2.0])):
        np.testing.assert_allclose(so3.rotation_between(a, 2 * a), np.eye(3), atol=1e-15)
        R = so3.rotation_between(a, -a)
        np.testing.assert_allclose(R @ a, -a, atol=1e-14)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)


def test_angle_deg_and_tilt_basis() -> None:
    assert so3.angle_deg(ref_exp(np.radians(37.0) * np.array([0.0, 0.6, 0.8]))) == \
        pytest.approx(37.0, abs=1e-10)
    for g in (np.array([0.0, 0.0, -1.0]), np.array([0.99, 0.1, 0.0]), np.array([0.1, 0.2, 3.0])):
        B = so3.tilt_basis(g)
        assert B.shape == (3, 2)
        np.testing.assert_allclose(B.T @ B, np.eye(2), atol=1e-15)
        np.testing.assert_allclose(B.T @ g, 0.0, atol=1e-15)


def test_the_filters_residual_rows_match_the_numpy_formulas():
    """The compiled residual pass (attitude log, lever arm, the Jacobian parts) against the
    formulas written with this module's functions, at random attitudes and at errors near
    zero and near pi (where the log switches its branches)."""
    from mocap_calib.core.position.kalman import residual_rows

    rng = np.random.default_rng(3)
    W, m1 = 3, 7
    R_WM = so3.exp(rng.normal(size=(W, m1, 3)))
    R_MI = so3.exp(rng.normal(size=3))
    p_MI = rng.normal(size=3) * 0.1
    errors = rng.normal(size=(W, m1, 3)) * 0.05
    errors[0, 0] = [1e-10, -2e-10, 0.0]  # the series branches
    errors[0, 1] = [0.0, 0.0, 0.0]
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    errors[1, 0] = axis * (np.pi - 1e-4)  # Shepperd's other cases
    errors[1, 1] = -axis * (np.pi - 1e-3)
    errors[2, 2] = [0.0, 3.0, 0.1]
    errors[2, 3] = [3.1, 0.2, 0.0]
    Rbar = R_WM @ R_MI @ np.swapaxes(so3.exp(errors), -1, -2)
    p_WM, pbar = rng.normal(size=(W, m1, 3)), rng.normal(size=(W, m1, 3))

    rows = residual_rows(R_MI, p_MI, R_WM, p_WM, Rbar, pbar)
    E = np.swapaxes(Rbar, -1, -2) @ R_WM @ R_MI
    r_rot = so3.log(E)
    np.testing.assert_allclose(r_rot, errors, atol=1e-9)  # the construction's own error
    np.testing.assert_allclose(rows.r[..., 0:3], r_rot, rtol=0, atol=1e-13)
    Jp = Rbar @ R_MI.T
    np.testing.assert_allclose(rows.r[..., 3:6], p_WM - pbar + Jp @ p_MI, rtol=0, atol=1e-13)
    Jinv = so3.right_jacobian_inv(r_rot)
    np.testing.assert_allclose(rows.Jinv, Jinv, rtol=0, atol=1e-11)
    np.testing.assert_allclose(rows.Pm_rot, Jinv @ np.swapaxes(E, -1, -2), rtol=0, atol=1e-11)
    np.testing.assert_allclose(rows.Jp, Jp, rtol=0, atol=1e-14)
    np.testing.assert_allclose(rows.Hq, Rbar @ so3.hat(R_MI.T @ p_MI), rtol=0, atol=1e-14)
    alone = residual_rows(R_MI, p_MI, R_WM, p_WM, Rbar, pbar, jacobians=False)
    assert np.array_equal(alone.r, rows.r) and alone.Jinv.size == 0


def test_the_compiled_log_of_many_rotations_matches_scipy():
    """From :data:`so3.COMPILED_LOG` rotations on, the log runs compiled: against scipy's
    rotation vectors, at random rotations and at angles near zero and near pi (every branch of
    Shepperd's method)."""
    rng = np.random.default_rng(11)
    phi = rng.normal(size=(so3.COMPILED_LOG + 40, 3))
    axes = np.eye(3)
    for i in range(3):
        phi[i] = axes[i] * (np.pi - 1e-5)  # the three diagonal cases
    phi[3] = [1e-13, 0.0, -2e-13]
    phi[4] = 0.0
    R = Rotation.from_rotvec(phi).as_matrix()
    got = so3.log(R.reshape(2, -1, 3, 3)).reshape(-1, 3)
    np.testing.assert_allclose(got, Rotation.from_matrix(R).as_rotvec(), rtol=0, atol=1e-9)
    np.testing.assert_allclose(got, so3.quat_to_rotvec(so3.rotmat_to_quat(R)), rtol=0,
                               atol=1e-14)
