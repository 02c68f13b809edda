"""Numerical checks of the multi-position fits' mathematics, against truth the code does not
compute: the accelerometer fit's analytic Jacobian against central differences of its own
residuals, and the RK4 gyro integrator against the closed-form attitude of a coning motion."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mocap_calib.core.intrinsics.multipos import MultiposPrior
from mocap_calib.core.intrinsics.multipos import fit as fit_module
from mocap_calib.core.intrinsics.multipos.fit import accel_model, fit_accel
from mocap_calib.core.model import so3
from mocap_calib.core.model.preint import quat_increments, quat_product, sample_nodes

G = 9.81


def _central_differences(fun, p: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    cols = []
    for k in range(len(p)):
        d = np.zeros(len(p))
        d[k] = eps
        cols.append((fun(p + d) - fun(p - d)) / (2 * eps))
    return np.stack(cols, axis=1)


def _accel_truth(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A lower-triangular ``M_a`` a few percent off identity, a bias, and ``n`` interval means
    ``M_a h + b`` of true specific forces ``|h| = g`` in random directions (noise-free)."""
    M = np.tril(np.eye(3) + rng.normal(0.0, 0.03, (3, 3)))
    b = rng.uniform(-0.3, 0.3, 3)
    u = rng.normal(size=(n, 3))
    h = G * u / np.linalg.norm(u, axis=1, keepdims=True)
    return M, b, h @ M.T + b


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_accel_jacobian_matches_central_differences(seed: int) -> None:
    """At random parameters (away from the optimum, so every term of the Jacobian matters)."""
    rng = np.random.default_rng(seed)
    _, _, means = _accel_truth(rng, 30)
    sig = rng.uniform(2e-3, 2e-2, 30)
    p = np.concatenate([np.array([1.0, 0.0, 1.0, 0.0, 0.0, 1.0]) + rng.normal(0, 0.05, 6),
                        rng.normal(0.0, 0.3, 3)])
    _, J = accel_model(p, means, sig, G)
    J_num = _central_differences(lambda x: accel_model(x, means, sig, G)[0], p)
    # Central differences with eps 1e-6 are good to ~1e-8 relative here; a wrong index or
    # sign in one column is off by O(1).
    assert np.max(np.abs(J - J_num)) < 1e-6 * np.max(np.abs(J_num))


def test_fit_accel_passes_a_correct_jacobian_and_recovers_exact_truth(monkeypatch) -> None:
    """The ``jac`` callable ``fit_accel`` hands to ``least_squares`` (data rows and prior rows)
    is the derivative of its ``fun``, and noise-free means give back the true M_a, b_a."""
    rng = np.random.default_rng(7)
    M_true, b_true, means = _accel_truth(rng, 24)
    sig = np.full(24, 5e-3)
    seen = {}
    real = fit_module.least_squares

    def spy(fun, x0, jac, **kw):
        seen["fun"], seen["jac"] = fun, jac
        return real(fun, x0, jac=jac, **kw)

    monkeypatch.setattr(fit_module, "least_squares", spy)
    # A prior on some entries: its rows enter ``fun`` and ``jac`` too; centred on the truth so
    # that it does not move the noise-free optimum.
    sig_M = np.full((3, 3), np.inf)
    sig_M[1, 0] = sig_M[2, 2] = 1e-3
    prior = MultiposPrior({"accel_matrix": M_true, "accel_bias": b_true},
                          {"accel_matrix": sig_M, "accel_bias": np.array([np.inf, 0.01, np.inf])})
    res = fit_accel(means, sig, G, prior)
    for p in (rng.normal(0.0, 0.05, 9) + np.array([1, 0, 1, 0, 0, 1, 0, 0, 0.0]),
              rng.normal(0.0, 0.05, 9) + np.array([1, 0, 1, 0, 0, 1, 0, 0, 0.0])):
        J = seen["jac"](p)
        assert J.shape == (24 + 3, 9)
        J_num = _central_differences(seen["fun"], p)
        assert np.max(np.abs(J - J_num)) < 1e-6 * np.max(np.abs(J_num))
    assert res.ok
    assert np.max(np.abs(res.M - M_true)) < 1e-9
    assert np.max(np.abs(res.b - b_true)) < 1e-9


# --------------------------------------------------------------------------------------------
# Coning
# --------------------------------------------------------------------------------------------

def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


# Classic coning: R(t) = Rz(W t) Rx(beta) Rz(-W t), a body tilted by beta whose tilt axis turns
# at W. With A = Rz(W t), dA/dt = W [z]x A, so dR/dt = W ([z]x R - R [z]x) and the body rate
# [w]x = R^T dR/dt = W ([R^T z]x - [z]x), i.e. w = W (R^T z - z). R^T z = A Rx(-beta) z
# = A [0, sin b, cos b], hence w(t) = W [-sin b sin Wt, sin b cos Wt, cos b - 1]: a rate of
# constant size whose axis turns, and no net rotation over a period. The integrator starts at
# identity, so it must give R(0)^T R(T).
CONE_HZ, BETA, DURATION = 2.0, 0.3, 10.0
OMEGA = 2 * np.pi * CONE_HZ


def _cone_rate(t: np.ndarray) -> np.ndarray:
    s, c = np.sin(BETA), np.cos(BETA)
    return OMEGA * np.stack([-s * np.sin(OMEGA * t), s * np.cos(OMEGA * t),
                             np.full_like(t, c - 1.0)], axis=-1)


def _cone_attitude(t: float) -> np.ndarray:
    return _rx(BETA).T @ _rz(OMEGA * t) @ _rx(BETA) @ _rz(-OMEGA * t)


def test_coning_closed_form_is_the_solution_of_the_rate() -> None:
    """The derivation above, checked by a fine adaptive integration of dq/dt = q (0, w) / 2."""
    def f(t: float, q: np.ndarray) -> np.ndarray:
        return 0.5 * so3.quat_multiply(q, np.r_[0.0, _cone_rate(np.array(t))])

    sol = solve_ivp(f, (0.0, DURATION), [1.0, 0.0, 0.0, 0.0], method="DOP853",
                    rtol=1e-12, atol=1e-12)
    q = sol.y[:, -1] / np.linalg.norm(sol.y[:, -1])
    assert so3.angle_deg(so3.quat_to_rotmat(q).T @ _cone_attitude(DURATION)) < 1e-7


#: (rate Hz, tolerance deg) after 10 s of 2 Hz coning with a 0.3 rad cone (|w| = 3.8 rad/s).
#: The integrator, fed rates at the samples only, interpolates them linearly to the RK4
#: midpoints; that costs 0.83 deg at 100 Hz and 0.21 deg at 200 Hz (second order). A
#: per-step fixed-axis integrator (exact for any rate about a fixed axis) is off by 1.65 and
#: 0.41 deg, the commuting approximation exp(sum w dt) by 38 deg.
CONING_TOL = {100.0: 1.0, 200.0: 0.25}


def _fixed_axis(nodes: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """Each step rotated about the axis of its Simpson-integrated rate: no coning term."""
    R = np.eye(3)
    steps = (nodes[0:-1:2] + 4 * nodes[1::2] + nodes[2::2]) / 6.0 * dt[:, None]
    for v in steps:
        R = R @ so3.exp(v)
    return R


@pytest.mark.parametrize("rate", sorted(CONING_TOL))
def test_rk4_integrator_follows_coning(rate: float) -> None:
    t = np.arange(int(DURATION * rate) + 1) / rate
    nodes = sample_nodes(_cone_rate(t))
    dt = np.diff(t)
    truth = _cone_attitude(DURATION)
    q = quat_product(quat_increments(nodes, dt))
    err = so3.angle_deg(so3.quat_to_rotmat(q).T @ truth)
    assert err < CONING_TOL[rate], f"{rate:.0f} Hz: {err:.4f} deg after {DURATION:.0f} s"
    # The tolerance is tight enough to catch an integrator that ignores coning.
    assert so3.angle_deg(_fixed_axis(nodes, dt).T @ truth) > 1.5 * CONING_TOL[rate]
    assert so3.angle_deg(so3.exp(np.sum(nodes[1::2] * dt[:, None], axis=0)).T @ truth) > 10.0


def test_rk4_coning_error_is_second_order() -> None:
    """Halving the step quarters the error (linear rate interpolation between samples); a
    first-order integrator would only halve it."""
    errs = []
    for rate in (100.0, 200.0, 400.0):
        t = np.arange(int(DURATION * rate) + 1) / rate
        q = quat_product(quat_increments(sample_nodes(_cone_rate(t)), np.diff(t)))
        errs.append(so3.angle_deg(so3.quat_to_rotmat(q).T @ _cone_attitude(DURATION)))
    ratios = np.array(errs[:-1]) / np.array(errs[1:])
    assert np.all((ratios > 3.6) & (ratios < 4.4)), (errs, ratios)
