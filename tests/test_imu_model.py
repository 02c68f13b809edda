"""The IMU measurement model: ``forward`` follows the conventions' formulas, ``correct`` inverts
it for every combination of effects, and the sensitivities ``dw``/``df`` (and the time
derivatives ``dw_du``/``df_du``) match finite differences."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.model.imu_model import Intrinsics, correct, forward

IMU_EFFECTS = ("gyro_scale_misalignment", "accel_scale_misalignment", "gyro_g_sensitivity",
               "gyro_bias_drift", "accel_bias_drift")

# Every subset of the effects that act through matrices and trends, with the world and clock
# effects (which must not change the samples' values); the kinds that need the motion's
# derivative or move samples in time have their own tests below.
MATRIX_AND_WORLD = (*IMU_EFFECTS, "time_offset", "gravity_magnitude", "clock_drift")
ALL_MODELS = [Model(tuple(c)) for r in range(len(MATRIX_AND_WORLD) + 1)
              for c in itertools.combinations(MATRIX_AND_WORLD, r)]


def true_values(seed: int) -> dict[str, np.ndarray]:
    """Effect values in the form of the conventions (matrices as M, not M - I)."""
    rng = np.random.default_rng(seed)
    return {
        "gyro_scale_misalignment": np.eye(3) + 0.02 * rng.normal(size=(3, 3)),
        "accel_scale_misalignment": np.eye(3) + np.tril(0.02 * rng.normal(size=(3, 3))),
        "gyro_g_sensitivity": 2e-3 * rng.normal(size=(3, 3)),
        "gyro_bias_drift": 1e-3 * rng.normal(size=3),
        "accel_bias_drift": 1e-2 * rng.normal(size=3),
        "gyro_bias": 0.02 * rng.normal(size=3),
        "accel_bias": 0.1 * rng.normal(size=3),
    }


def make_params(model: Model, vals: dict[str, np.ndarray], t_mid: float) -> Intrinsics:
    effects = {}
    for name in model.effects:
        if name in IMU_EFFECTS:
            eff = EFFECTS[name]
            theta = eff.theta_from_report(vals[name])
            # The parameter vector must describe the same matrix / vector.
            np.testing.assert_allclose(np.asarray(eff.report_value(theta)), vals[name],
                                       rtol=0, atol=1e-15)
            effects[name] = theta
    return Intrinsics(vals["gyro_bias"].copy(), vals["accel_bias"].copy(), effects, t_mid)


def conventions_forward(model: Model, vals: dict[str, np.ndarray], w: np.ndarray,
                        f: np.ndarray, u: np.ndarray, t_mid: float) -> tuple[np.ndarray,
                                                                             np.ndarray]:
    """``w_m = M_g w + G f + b_g + r_g (u - t_mid)``, ``a_m = M_a f + b_a + r_a (u - t_mid)``,
    with absent effects at their identity (docs/conventions.md)."""
    M_g = vals["gyro_scale_misalignment"] if model.has("gyro_scale_misalignment") else np.eye(3)
    M_a = vals["accel_scale_misalignment"] if model.has("accel_scale_misalignment") else np.eye(3)
    G = vals["gyro_g_sensitivity"] if model.has("gyro_g_sensitivity") else np.zeros((3, 3))
    r_g = vals["gyro_bias_drift"] if model.has("gyro_bias_drift") else np.zeros(3)
    r_a = vals["accel_bias_drift"] if model.has("accel_bias_drift") else np.zeros(3)
    dt = (u - t_mid)[:, None]
    gyro = np.einsum("ij,nj->ni", M_g, w) + np.einsum("ij,nj->ni", G, f) + vals["gyro_bias"] \
        + dt * r_g
    accel = np.einsum("ij,nj->ni", M_a, f) + vals["accel_bias"] + dt * r_a
    return gyro, accel


def signals(n: int = 40, seed: int = 11) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    w = rng.normal(0.0, 1.5, (n, 3))
    f = rng.normal(0.0, 5.0, (n, 3)) + np.array([0.0, 0.0, 9.81])
    u = np.sort(rng.uniform(0.0, 30.0, n))
    return w, f, u


@pytest.mark.parametrize("model", ALL_MODELS, ids=str)
def test_forward_follows_conventions_and_correct_inverts_it(model: Model) -> None:
    vals = true_values(1)
    t_mid = 14.2
    params = make_params(model, vals, t_mid)
    w, f, u = signals()
    gyro, accel = forward(model, params, w, f, u)
    g_ref, a_ref = conventions_forward(model, vals, w, f, u, t_mid)
    np.testing.assert_allclose(gyro, g_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(accel, a_ref, rtol=0, atol=1e-12)
    out = correct(model, params, gyro, accel, u)
    np.testing.assert_allclose(out.w, w, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out.f, f, rtol=0, atol=1e-12)


def test_forward_is_sensitive_to_every_effect() -> None:
    """Guard against a model that ignores an effect (the tests above would still pass if both
    the reference and forward ignored it only for identity values)."""
    vals = true_values(2)
    w, f, u = signals()
    base_g, base_a = forward(Model(), make_params(Model(), vals, 10.0), w, f, u)
    for name in IMU_EFFECTS:
        m = Model((name,))
        g, a = forward(m, make_params(m, vals, 10.0), w, f, u)
        changed = np.abs(g - base_g).max() + np.abs(a - base_a).max()
        assert changed > 1e-3, name


def numeric_jacobians(model: Model, params: Intrinsics, gyro: np.ndarray, accel: np.ndarray,
                      u: np.ndarray, eps: float = 1e-6) -> dict[str, tuple[np.ndarray,
                                                                          np.ndarray]]:
    """Central differences of ``correct``'s ``w`` and ``f`` w.r.t. every parameter block."""
    blocks: dict[str, np.ndarray] = {"gyro_bias": params.gyro_bias,
                                     "accel_bias": params.accel_bias}
    for name in model.effects:
        if name in IMU_EFFECTS:
            blocks[name] = params.effects[name]
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, theta in blocks.items():
        k = len(theta)
        dw = np.empty(gyro.shape + (k,))
        df = np.empty(gyro.shape + (k,))
        for j in range(k):
            res = []
            for sign in (1.0, -1.0):
                th = np.array(theta, dtype=float)
                th[j] += sign * eps
                if name == "gyro_bias":
                    p = Intrinsics(th, params.accel_bias, params.effects, params.t_mid)
                elif name == "accel_bias":
                    p = Intrinsics(params.gyro_bias, th, params.effects, params.t_mid)
                else:
                    p = Intrinsics(params.gyro_bias, params.accel_bias,
                                   {**params.effects, name: th}, params.t_mid)
                c = correct(model, p, gyro, accel, u, sensitivities=False)
                res.append((c.w, c.f))
            dw[..., j] = (res[0][0] - res[1][0]) / (2 * eps)
            df[..., j] = (res[0][1] - res[1][1]) / (2 * eps)
        out[name] = (dw, df)
    return out


@pytest.mark.parametrize("model", [Model(tuple(c)) for r in range(len(IMU_EFFECTS) + 1)
                                   for c in itertools.combinations(IMU_EFFECTS, r)], ids=str)
def test_sensitivities_match_finite_differences(model: Model) -> None:
    vals = true_values(3)
    params = make_params(model, vals, 7.5)
    w, f, u = signals(n=12, seed=4)
    gyro, accel = conventions_forward(model, vals, w, f, u, 7.5)
    out = correct(model, params, gyro, accel, u)
    num = numeric_jacobians(model, params, gyro, accel, u)
    assert set(out.dw) == set(num)
    assert set(out.df) == set(num)
    for name, (dw_num, df_num) in num.items():
        assert out.dw[name].shape == dw_num.shape, name
        assert out.df[name].shape == df_num.shape, name
        np.testing.assert_allclose(out.dw[name], dw_num, rtol=0, atol=1e-7, err_msg=name)
        np.testing.assert_allclose(out.df[name], df_num, rtol=0, atol=1e-7, err_msg=name)


def test_bias_sensitivities_base_model() -> None:
    """Base model: ``w = w_m - b_g``, ``f = a_m - b_a``, so the blocks are -I and 0."""
    vals = true_values(5)
    params = make_params(Model(), vals, 0.0)
    w, f, u = signals(n=3)
    out = correct(Model(), params, w, f, u)
    neg_eye = np.broadcast_to(-np.eye(3), (3, 3, 3))
    np.testing.assert_array_equal(out.dw["gyro_bias"], neg_eye)
    np.testing.assert_array_equal(out.df["accel_bias"], neg_eye)
    np.testing.assert_array_equal(out.dw["accel_bias"], np.zeros((3, 3, 3)))
    np.testing.assert_array_equal(out.df["gyro_bias"], np.zeros((3, 3, 3)))


@pytest.mark.parametrize("model", [Model(), Model(IMU_EFFECTS)], ids=str)
def test_time_derivatives_of_corrected_signals(model: Model) -> None:
    """``dw_du``/``df_du`` for raw signals that are smooth functions of time: compare with the
    central difference of the corrected signals over ``u``."""
    vals = true_values(6)
    params = make_params(model, vals, 3.0)
    u = np.linspace(0.0, 6.0, 25)

    def raw(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k = np.array([0.7, 1.3, 2.1])
        gyro = np.sin(np.outer(t, k)) + 0.1
        accel = 3.0 * np.cos(np.outer(t, k[::-1])) + np.array([0.0, 0.0, 9.81])
        return gyro, accel

    def raw_dot(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k = np.array([0.7, 1.3, 2.1])
        return np.cos(np.outer(t, k)) * k, -3.0 * np.sin(np.outer(t, k[::-1])) * k[::-1]

    g, a = raw(u)
    gd, ad = raw_dot(u)
    out = correct(model, params, g, a, u, gd, ad)
    h = 1e-5
    gp, ap = raw(u + h)
    gm, am = raw(u - h)
    plus = correct(model, params, gp, ap, u + h, sensitivities=False)
    minus = correct(model, params, gm, am, u - h, sensitivities=False)
    np.testing.assert_allclose(out.dw_du, (plus.w - minus.w) / (2 * h), rtol=0, atol=1e-8)
    np.testing.assert_allclose(out.df_du, (plus.f - minus.f) / (2 * h), rtol=0, atol=1e-8)


def test_size_effect_forward_follows_the_formula_and_correct_inverts_it() -> None:
    """``a_m,i = e_i.(f + alpha x r_i + w x (w x r_i)) + b_a,i`` (x accelerometer at the
    origin), written out here; ``correct`` undoes it, and its sensitivities match finite
    differences."""
    rng = np.random.default_rng(5)
    w, f, u = signals()
    alpha = rng.normal(0.0, 3.0, w.shape)
    r = rng.normal(0.0, 0.01, 6)
    model = Model(("accel_size_effect", "accel_scale_misalignment"))
    M_a = np.eye(3) + np.tril(0.02 * rng.normal(size=(3, 3)))
    eff = EFFECTS["accel_scale_misalignment"]
    params = Intrinsics(np.zeros(3), 0.1 * np.ones(3),
                        {"accel_size_effect": r, "accel_scale_misalignment":
                         eff.theta_from_report(M_a)}, 0.0)
    gyro, accel = forward(model, params, w, f, u, alpha)
    sensed = f.copy()
    for i, ri in ((1, r[0:3]), (2, r[3:6])):
        sensed[:, i] += (np.cross(alpha, ri) + np.cross(w, np.cross(w, ri)))[:, i]
    np.testing.assert_allclose(accel, sensed @ M_a.T + 0.1, atol=1e-12)
    np.testing.assert_allclose(gyro, w, atol=1e-12)
    # The raw gyro's derivative is alpha here (no gyro effects).
    c = correct(model, params, gyro, accel, u, gyro_dot=alpha, accel_dot=np.zeros_like(f))
    np.testing.assert_allclose(c.f, f, atol=1e-10)
    eps = 1e-7
    for k in range(6):
        d = np.zeros(6)
        d[k] = eps
        p2 = Intrinsics(params.gyro_bias, params.accel_bias,
                        {**params.effects, "accel_size_effect": r + d}, 0.0)
        c2 = correct(model, p2, gyro, accel, u, gyro_dot=alpha, accel_dot=np.zeros_like(f),
                     sensitivities=False)
        np.testing.assert_allclose((c2.f - c.f) / eps, c.df["accel_size_effect"][..., k],
                                   atol=1e-6)


def test_preintegration_in_chunks_gives_the_same_numbers(monkeypatch: pytest.MonkeyPatch) -> None:
    """Spans are preintegrated in chunks (memory); chunk boundaries change nothing, even where
    chunks pad their steps to different numbers of pieces."""
    from mocap_calib.core.model import preint

    rng = np.random.default_rng(3)
    u = np.cumsum(rng.uniform(0.004, 0.006, 2000))
    gyro, accel = rng.normal(0, 1, (2000, 3)), rng.normal(0, 9.8, (2000, 3))
    edges = np.sort(rng.uniform(u[5], u[-5], 120))
    tau0, tau1 = edges[:-1], edges[1:]

    def run() -> preint.StepIncrements:
        return preint.preintegrate_spans(u, gyro, accel, tau0, tau1, 0.0013,
                                         lambda g, a, t: (g - 0.01, a + 0.1))

    whole = run()
    monkeypatch.setattr(preint, "SPAN_CHUNK", 7)
    chunked = run()
    for f in ("dR", "dv", "dp", "A", "C", "B", "D"):
        np.testing.assert_array_equal(getattr(chunked, f), getattr(whole, f), err_msg=f)
