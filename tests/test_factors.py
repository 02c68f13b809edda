"""Custom factors' Jacobians against numerical derivatives, in GTSAM's tangent spaces."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from mocap_calib.core.model import so3
from mocap_calib.core.stages.attitude import attitude_errors
from mocap_calib.core.stages.velocity import _Data, velocity_factor

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset


def test_attitude_factor_jacobians():
    rng = np.random.default_rng(0)
    n = 7
    R = so3.exp(rng.normal(size=3))
    dRM = so3.exp(rng.normal(size=(n, 3)))
    dRI = so3.exp(rng.normal(size=(n, 3)) * 0.5)
    J = rng.normal(size=(n, 3, 3)) * 0.3
    b0 = rng.normal(size=3) * 0.01
    b = b0 + rng.normal(size=3) * 0.01
    e, HR, Hb = attitude_errors(R, b, dRM, dRI, J, b0)
    eps = 1e-7
    for i in range(3):
        d = np.eye(3)[i] * eps
        eR = attitude_errors(R @ so3.exp(d), b, dRM, dRI, J, b0, jacobians=False)[0]
        np.testing.assert_allclose((eR - e) / eps, HR[:, :, i], atol=2e-6)
        eb = attitude_errors(R, b + d, dRM, dRI, J, b0, jacobians=False)[0]
        np.testing.assert_allclose((eb - e) / eps, Hb[:, :, i], atol=2e-6)


def test_velocity_factor_jacobians_with_gtsam_unit3():
    """The Jacobians the velocity stage's factors hand to GTSAM (``velocity_factor``, which
    its factors call) against numerical derivatives of the same function's error."""
    rng = np.random.default_rng(1)
    n = 5
    data = _Data(rng.normal(size=(n, 3)), rng.normal(size=(n, 3, 3)),
                 so3.exp(rng.normal(size=(n, 3))), rng.normal(size=(n, 3)),
                 rng.normal(size=(n, 3, 3)), rng.uniform(0.3, 0.7, n))
    b0 = rng.normal(size=3) * 0.05
    b = b0 + 0.01
    p = rng.normal(size=3) * 0.1
    u3 = gtsam.Unit3(rng.normal(size=3))
    g = 9.81
    e, Hb, Hp, Hg = velocity_factor(data, b, p, u3, g, b0)
    eps = 1e-7
    for i in range(3):
        d = np.eye(3)[i] * eps
        np.testing.assert_allclose((velocity_factor(data, b + d, p, u3, g, b0)[0] - e) / eps,
                                   Hb[:, :, i], atol=1e-5)
        np.testing.assert_allclose((velocity_factor(data, b, p + d, u3, g, b0)[0] - e) / eps,
                                   Hp[:, :, i], atol=1e-5)
    for i in range(2):
        u2 = u3.retract(np.eye(2)[i] * eps)
        np.testing.assert_allclose((velocity_factor(data, b, p, u2, g, b0)[0] - e) / eps,
                                   Hg[:, :, i], atol=1e-4)


def _short_flight():
    """A 12 s simulated flight (seed 3, a 3 ms clock offset) prepared and cut into 3 s windows
    at a clock offset 0.2 ms from the truth: (simulation, session, windows, offset)."""
    from mocap_calib.core.position.engine import make_windows
    from mocap_calib.core.prepare.session import local_derivative, prepare
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    sim = simulate_flight(SimConfig(seed=3, duration=12.0, effects={"time_offset": [0.003]}))
    s = prepare(sim.imu, sim.mocap)
    _, v, _ = local_derivative(s.tau, s.p_WM, 5, s.gap)
    delta = s.clock_shift + 0.0032
    return sim, s, make_windows(s, delta, 3.0, 200.0, v), delta


def test_position_graph_gradient_matches_numerical_derivative_of_its_cost():
    """End to end through GTSAM: the linearised window factors (compressed, per key) give the
    gradient of the graph's nonlinear cost in each variable's tangent space.

    Gauss-Newton holds the noise model (the Kalman filter's transition and gains and the
    lever-arm term of the mocap noise) fixed at the linearisation point, so the gradient differs
    from the full cost's by the noise model's own dependence on the parameters: under 1 % of
    each key's largest component, and under 2 % for the knots, whose end rows (a window's end
    bias meeting the next knot) hold the filter's end state, which moves with its gains
    (measured: 1.4 % and 1.7 % on the knots' gyro components; 0.3 % with the end rows' gyro
    part weighted off; the end state's Jacobian columns against its numerical derivative:
    equal to 1 % on the own bias). A wrong key order, sign or tangent space would be off by
    far more."""
    from mocap_calib.core.model.effects import Model
    from mocap_calib.core.model.types import NoiseModel
    from mocap_calib.core.position.graph import (
        KEY_G,
        KEY_P,
        KEY_R,
        KEY_T,
        PositionInit,
        Take,
        TakeStart,
        build_position_graph,
        key_effect,
        key_knot,
        key_time,
    )

    sim, s, win, delta = _short_flight()
    tr = sim.truth
    rng = np.random.default_rng(2)
    init = PositionInit(
        so3.quat_to_rotmat(np.array(tr["T_marker_imu"]["rotation_wxyz"])) @ so3.exp([1e-3, 0, 0]),
        np.array(tr["T_marker_imu"]["translation"]) + 1e-3,
        np.array(tr["gravity_in_mocap"]), 9.81,
        [TakeStart(delta, np.array(tr["gyro_bias"]) + 1e-4, np.array(tr["accel_bias"]) + 1e-2),
         TakeStart(delta + 2e-4, np.array(tr["gyro_bias"]) - 1e-4,
                   np.array(tr["accel_bias"]) - 1e-2)],
        {"accel_scale_misalignment": rng.normal(0, 1e-3, 6)})
    model = Model.parse("base+time_offset+accel_scale_misalignment")
    # Two takes (the same recording twice, its second clock 0.2 ms off): the second take's
    # clock and knots are checked too.
    pg = build_position_graph([Take(s, win), Take(s, win)], model, NoiseModel(), init)
    values = pg.values
    grad = pg.graph.linearize(values).gradientAtZero()
    base = pg.graph.error(values)
    eps = 1e-7
    checks = [(KEY_R, 3), (KEY_P, 3), (KEY_G, 2), (KEY_T, 1), (key_knot(1), 6),
              (key_effect(1), 6), (key_time(1), 1), (key_knot(win.count + 1), 6)]
    for key, dim in checks:
        g_ana = np.asarray(grad.at(key))
        g_num = np.zeros(dim)
        for i in range(dim):
            d = gtsam.VectorValues()
            d.insert(key, np.eye(dim)[i] * eps)
            g_num[i] = (pg.graph.error(values.retract(d)) - base) / eps
        scale = np.abs(g_ana).max()
        share = 2e-2 if key in (key_knot(1), key_knot(win.count + 1)) else 1e-2
        np.testing.assert_allclose(g_num, g_ana, atol=share * scale + 1e-3,
                                   err_msg=f"key {gtsam.DefaultKeyFormatter(key)}")


def test_session_mean_jacobian_matches_numerical_derivative():
    """The session's time-mean bias (its posterior mean from the filters' bias integrals and
    the end rows) moves with every variable as its Jacobian says: within 5 % of each key's
    largest derivative (measured: rotation, position, gravity <= 0.4 %, clock 1.7 %, the knots
    <= 3.4 %: the integrals move with the filter's gains too, which the linearisation holds
    fixed). The gyro rows, which the data barely move from the knots, agree to 0.1 %."""
    from mocap_calib.core.gtsam_tools import information_matrix
    from mocap_calib.core.model.effects import Model
    from mocap_calib.core.model.types import NoiseModel
    from mocap_calib.core.position.covariance import CovarianceInputs, _mean_columns
    from mocap_calib.core.position.graph import (
        KEY_G,
        KEY_P,
        KEY_R,
        KEY_T,
        PositionInit,
        Take,
        TakeStart,
        build_position_graph,
        key_knot,
    )

    sim, s, win, delta = _short_flight()
    tr = sim.truth
    init = PositionInit(
        so3.quat_to_rotmat(np.array(tr["T_marker_imu"]["rotation_wxyz"])) @ so3.exp([1e-3, 0, 0]),
        np.array(tr["T_marker_imu"]["translation"]) + 1e-3,
        np.array(tr["gravity_in_mocap"]), 9.81,
        [TakeStart(delta, np.array(tr["gyro_bias"]) + 1e-4, np.array(tr["accel_bias"]) + 1e-2)],
        {})
    pg = build_position_graph([Take(s, win)], Model.parse("base+time_offset"), NoiseModel(),
                              init)
    values = pg.values

    def mean(vals: gtsam.Values) -> np.ndarray:
        return pg.session_means(vals)[0].value(pg.theta(vals).knots)

    _, offsets, n = information_matrix(pg.graph, values)
    blocks = [(name, d) for name, d in pg.problem.layout.blocks if name != "knot"]
    inp = CovarianceInputs(pg.shared_keys, blocks, [win], pg.knot0, [pg.theta(values).knots],
                           pg.session_means(values), True)
    E = _mean_columns(inp, 0, offsets, n)
    assert win.count >= 4
    for key, dim, eps in [(KEY_R, 3, 1e-5), (KEY_P, 3, 1e-5), (KEY_G, 2, 1e-5), (KEY_T, 1, 1e-6),
                          (key_knot(0), 6, 1e-5), (key_knot(1), 6, 1e-5),
                          (key_knot(win.count - 1), 6, 1e-5)]:
        num = np.zeros((6, dim))
        for i in range(dim):
            up, down = gtsam.VectorValues(), gtsam.VectorValues()
            up.insert(key, np.eye(dim)[i] * eps)
            down.insert(key, -np.eye(dim)[i] * eps)
            num[:, i] = (mean(values.retract(up)) - mean(values.retract(down))) / (2 * eps)
        ana = E[offsets[key]:offsets[key] + dim].T
        name = gtsam.DefaultKeyFormatter(key)
        np.testing.assert_allclose(ana, num, atol=0.05 * np.abs(num).max(), err_msg=name)
        np.testing.assert_allclose(ana[0:3], num[0:3], atol=1e-3 * np.abs(num).max() + 1e-9,
                                   err_msg=name)


def test_batch_cache_follows_the_values_between_and_within_passes() -> None:
    """The batch is evaluated once per set of values: every pass at new values (error,
    linearize, a subset of factors in a Python loop) must still see the new values, never a
    cached evaluation of other ones, however small the change; equal values (GTSAM passes
    copies) reuse the evaluation."""
    import gtsam

    from mocap_calib.core.gtsam_tools import BatchFactors, BatchOutput

    n = 50

    def evaluate(v: gtsam.Values) -> BatchOutput:  # factor i: x_shared + y_i - i
        x = float(v.atVector(0)[0])
        return BatchOutput([np.array([x + float(v.atVector(1 + i)[0]) - i]) for i in range(n)],
                           [[np.eye(1), np.eye(1)] for _ in range(n)])

    batch = BatchFactors(evaluate, [[0, 1 + i] for i in range(n)],
                         gtsam.noiseModel.Unit.Create(1))
    graph = gtsam.NonlinearFactorGraph()
    factors = batch.factors()
    for f in factors:
        graph.add(f)

    def values(x: float, y: float) -> gtsam.Values:
        v = gtsam.Values()
        v.insert(0, np.array([x]))
        for i in range(n):
            v.insert(1 + i, np.array([y + i]))
        return v

    for x, y in [(0.0, 0.0), (1.0, 0.0), (1.0, 2.0), (-3.0, 2.0)]:
        assert graph.error(values(x, y)) == pytest.approx(0.5 * n * (x + y) ** 2)
    # Single factors called out of order, and in increasing order at changing values.
    for i, x in [(7, 1.0), (3, 2.0), (9, -1.0), (10, 5.0), (49, 0.5)]:
        assert factors[i].error(values(x, 0.0)) == pytest.approx(0.5 * x**2)
    assert batch.evaluations < 4 + 5 + 2
    # Equal values in a new object: no evaluation; the smallest change of one factor's own
    # key: evaluated again, and every factor sees it.
    before = batch.evaluations
    for i in (0, 17, 49):
        assert factors[i].error(values(0.5, 0.0)) == pytest.approx(0.125)
    assert batch.evaluations == before
    v = values(0.5, 0.0)
    v.update(1 + 17, np.array([np.nextafter(17.0, 18.0)]))
    err = np.sqrt(2.0 * np.array([factors[i].error(v) for i in range(n)]))
    assert batch.evaluations == before + 1
    assert err[17] == 0.5 + (np.nextafter(17.0, 18.0) - 17.0)
    assert np.all(np.delete(err, 17) == 0.5)


def test_spd_factor_solves_an_arrowhead_without_filling_it_in() -> None:
    """The information matrix: each window couples two knots (6 each) and the shared blocks,
    its variables scaled over decades (the real one's diagonal spans 4e2..9e5). The
    factorisation must solve it and stay sparse: scipy's default (COLAMD with partial
    pivoting) pivots off the diagonal and fills such a matrix in (here 16x, at 60 min half a
    dense one)."""
    import scipy.sparse as sp

    from mocap_calib.core.gtsam_tools import spd_factor

    rng = np.random.default_rng(5)
    W, ns = 400, 15
    n = 6 * (W + 1) + ns
    rows, cols, vals = [], [], []
    for w in range(W):
        idx = np.r_[np.arange(6 * w, 6 * w + 12), 6 * (W + 1) + np.arange(ns)]
        J = rng.normal(size=(30, len(idx)))
        r, c = np.meshgrid(idx, idx, indexing="ij")
        rows.append(r.ravel())
        cols.append(c.ravel())
        vals.append((J.T @ J).ravel())
    H = sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(n, n))
    D = sp.diags(10.0 ** rng.uniform(-3, 3, n))
    H = (D @ H @ D).tocsc()
    b = H @ rng.normal(size=(n, 3))
    x = spd_factor(H).solve(b)
    np.testing.assert_allclose(H @ x, b, rtol=1e-8, atol=1e-8 * np.abs(b).max())
    lu = spd_factor(H)
    assert lu.L.nnz + lu.U.nnz < 2 * H.nnz


def test_huber_stack_is_gtsams_robust_noise_model_on_each_factor() -> None:
    """One stacked factor with the Huber loss inside (the stages' keyframe intervals) must
    cost and linearise as GTSAM's Robust(Huber, Isotropic) noise model on every factor does:
    the same error, the same Hessian and gradient, the same LM solution."""
    import gtsam

    from mocap_calib.core.gtsam_tools import BatchFactors, BatchOutput, Huber, run_lm

    rng = np.random.default_rng(3)
    n, k, key_r, key_b = 200, 1.5, 0, 1
    A = rng.normal(size=(n, 3, 3))
    y = rng.normal(size=(n, 3)) + np.where(rng.random((n, 1)) < 0.2, 8.0, 0.0)  # outliers
    sig = rng.uniform(0.5, 2.0, n)

    def errors(v: gtsam.Values) -> tuple[np.ndarray, list[np.ndarray]]:
        # e_n = Log(R) (a nonlinear key) + A_n b - y_n
        phi = gtsam.Rot3.Logmap(v.atRot3(key_r))
        b = np.asarray(v.atVector(key_b))
        Jr = np.broadcast_to(gtsam.Rot3.LogmapDerivative(phi), (n, 3, 3))
        return phi + A @ b - y, [np.array(Jr), A]

    stacked = Huber(sig, k).factor(errors, [key_r, key_b])
    # The same factors one by one, robust in GTSAM.
    per = BatchFactors(lambda v: BatchOutput(
        list(errors(v)[0]), [[errors(v)[1][0][i], A[i]] for i in range(n)]),
        [[key_r, key_b]] * n,
        [gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(k),
                                        gtsam.noiseModel.Isotropic.Sigma(3, float(x)))
         for x in sig])
    graphs = []
    for batch in (stacked, per):
        g = gtsam.NonlinearFactorGraph()
        for f in batch.factors():
            g.add(f)
        graphs.append(g)
    v = gtsam.Values()
    v.insert(key_r, gtsam.Rot3.Rodrigues(0.1, -0.2, 0.3))
    v.insert(key_b, np.array([0.3, -0.1, 0.2]))
    e1, e2 = (g.error(v) for g in graphs)
    assert e1 == pytest.approx(e2, rel=1e-12)
    assert np.sum(Huber(sig, k).weights(errors(v)[0]) < 1) > 10  # the loss is exercised
    (H1, g1), (H2, g2) = (g.linearize(v).hessian() for g in graphs)
    np.testing.assert_allclose(H1, H2, rtol=1e-10, atol=1e-10 * np.abs(H2).max())
    np.testing.assert_allclose(g1, g2, rtol=1e-10, atol=1e-10 * np.abs(g2).max())
    s1, s2 = (run_lm(g, v, 50, relative_tol=1e-12)[0] for g in graphs)
    np.testing.assert_allclose(s1.atVector(key_b), s2.atVector(key_b), atol=1e-9)
    np.testing.assert_allclose(s1.atRot3(key_r).matrix(), s2.atRot3(key_r).matrix(),
                               atol=1e-9)


def test_predicted_decrease_is_half_the_squared_mahalanobis_step() -> None:
    """The Gauss-Newton step's predicted decrease, checked against the analytic value on a
    linear problem (a prior at 0 with sigma 2 on a 3-vector, started z sigmas away: 0.5 z^2),
    and LM with ``predicted_tol`` tries no step within it and converges from outside it."""
    import gtsam

    from mocap_calib.core.gtsam_tools import predicted_decrease, run_lm

    key = 7
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorVector(key, np.zeros(3),
                                      gtsam.noiseModel.Isotropic.Sigma(3, 2.0)))

    def at(x: list[float]) -> gtsam.Values:
        v = gtsam.Values()
        v.insert(key, np.array(x))
        return v

    assert predicted_decrease(graph, at([2.0, -4.0, 0.0])) == pytest.approx(0.5 * 5.0)
    near, far = at([0.02, 0.0, 0.0]), at([2.0, 0.0, 0.0])  # z = 0.01 (5e-5) and z = 1 (0.5)
    sol, rep = run_lm(graph, near, predicted_tol=1e-3)
    assert rep.iterations == 0 and rep.converged
    np.testing.assert_array_equal(sol.atVector(key), [0.02, 0.0, 0.0])
    sol, rep = run_lm(graph, far, predicted_tol=1e-3)
    assert rep.iterations >= 1 and rep.converged
    np.testing.assert_allclose(sol.atVector(key), 0.0, atol=0.1)


def test_near_trials_end_an_iteration_whose_dampings_all_fail() -> None:
    """Near the solution with ``near_trials`` an LM iteration tries that many dampings: with a
    Jacobian of the wrong sign no step lowers the cost, and the solve ends where it started
    after a few cost evaluations instead of LM's whole damping range; where steps succeed it
    reaches the same solution as LM alone."""
    import gtsam

    from mocap_calib.core.gtsam_tools import run_lm

    key, calls = 3, {"cost": 0}

    def bad(sign: float):
        def fn(this: gtsam.CustomFactor, v: gtsam.Values, H: list | None) -> np.ndarray:
            x = np.asarray(v.atVector(key))
            if H is None:
                calls["cost"] += 1
            else:
                H[0] = sign * np.eye(1)
            return x - 1.0
        graph = gtsam.NonlinearFactorGraph()
        graph.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(1, 1.0), [key], fn))
        return graph

    start = gtsam.Values()
    start.insert(key, np.array([1.5]))  # predicted decrease 0.125: near
    counts = []
    for trials in (None, 4):
        calls["cost"] = 0
        sol, rep = run_lm(bad(-1.0), start, predicted_tol=1e-3, near_trials=trials)
        assert rep.converged and rep.iterations == 1
        np.testing.assert_array_equal(sol.atVector(key), [1.5])
        counts.append(calls["cost"])
    # Four trials plus the costs at the start (the solve's, the pass's, each optimizer's).
    assert counts[1] <= 4 + 4 and counts[0] >= counts[1] + 8
    sols = [run_lm(bad(1.0), start, predicted_tol=1e-3, near_trials=t)[0] for t in (None, 4)]
    np.testing.assert_allclose(sols[0].atVector(key), 1.0, atol=1e-4)
    np.testing.assert_allclose(sols[1].atVector(key), sols[0].atVector(key), atol=1e-12)
