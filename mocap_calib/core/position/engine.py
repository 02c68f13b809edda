"""Position factors: whole windows of mocap poses against the IMU-propagated trajectory.

A window is a gap-free stretch of mocap samples (a few seconds). From the window's first mocap
pose the IMU, corrected by the current model, is integrated forward (RK4 between samples, see
:mod:`mocap_calib.core.model.preint`) and compared with every mocap pose in the window:

    r_k = [ Log(R_bar_k^T R_WM,k R_MI) ;  p_WM,k + R_WM,k p_MI - p_bar_k ]

The start velocity and pose of each window are nuisance (diffuse) and the IMU noise, the bias
random walk within the window and the mocap noise are all in the noise model: a Kalman filter
over the window's error state (attitude, position, velocity, gyro and accel bias deviations)
turns the correlated residuals into white innovations, and the same filter applied to the
residual Jacobian gives the whitened Jacobian. This is the exact Gaussian likelihood of the
window, computed in time linear in its length. Each window's whitened system is compressed to
its Gram matrix's Cholesky factor, so the factor GTSAM sees has ``p + 1`` rows.

All windows advance in lock-step (arrays of shape windows x steps), so the Python loop runs
over the steps of one window, not over the session.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import stats as sps

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.model.imu_model import (
    Corrected,
    Intrinsics,
    accel_lag,
    correct,
    imu_times,
    size_matrix,
)
from mocap_calib.core.model.preint import (
    StepIncrements,
    compose,
    hermite,
    integrate_pieces,
    pieces,
)
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.kalman import (
    DIFFUSE,
    Accumulator,
    Noise,
    filter_noise,
    likelihood_pass,
    predict_covariance,
    signals_at,
    step_mean,
)
from mocap_calib.core.position.threads import chunk_pool, split_windows
from mocap_calib.core.position.windows import (  # noqa: F401  (re-exported)
    EvalOut,
    Layout,
    Theta,
    Windows,
    layout_for,
    make_windows,
)
from mocap_calib.core.prepare.session import PreparedSession

Array = NDArray[np.float64]

#: Robust kernel threshold on a sample's whitened 6-D innovation norm (chi, 6 dof, 99.9%).
ROBUST_C = float(np.sqrt(sps.chi2.ppf(0.999, 6)))
#: Length (s) of the blocks of consecutive samples whose scores the sandwich covariance sums:
#: longer than the correlation of real mocap noise, short enough for many blocks per session.
SCORE_BLOCK_S = 1.0


@dataclass(frozen=True)
class _Residuals:
    r: Array  # (W, m+1, 6) attitude and position residuals
    Jinv: Array  # (W, m+1, 3, 3) right-Jacobian inverse of the attitude residual
    Pm_rot: Array  # (W, m+1, 3, 3) d r_rot / d (nominal attitude perturbation)
    R_WM: Array  # (W, m+1, 3, 3)


class PositionProblem:
    """Evaluates the window factors for all windows at once.

    Args:
        s: prepared session.
        model: active effects.
        noise: noise densities.
        windows: from :func:`make_windows`.
        chunk_steps: windows are processed in chunks of about this many samples (memory).
        split: split into two chunks at least (for the threads); off for small problems
            evaluated many times, where one batch costs less than two.
    """

    def __init__(self, s: PreparedSession, model: Model, noise: NoiseModel, windows: Windows,
                 chunk_steps: int = 40_000, split: bool = True) -> None:
        self.s = s
        self.model = model
        self.noise = noise
        self.win = windows
        self.layout = layout_for(model)
        self.chunks = split_windows(windows.count, windows.steps, chunk_steps, split)
        self.weights = np.ones(windows.idx.shape)
        self._local = threading.local()  # per-thread work buffers
        self.freeze = False
        self.collect_scores = False  # per-block scores in unfrozen evaluations (sandwich)
        self._ops: dict[int, dict[str, Array]] = {}

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, th: Theta, store: bool = False) -> EvalOut:
        pool = chunk_pool()
        if len(self.chunks) > 1 and pool is not None:
            outs = list(pool.map(lambda ic: self._evaluate_chunk(th, ic[1], store, ic[0]),
                                    enumerate(self.chunks)))
        else:
            outs = [self._evaluate_chunk(th, c, store, ci) for ci, c in enumerate(self.chunks)]
        cat = {f: (np.concatenate([getattr(o, f) for o in outs]) if getattr(outs[0], f) is not None
                   else None) for f in ("gram", "innovation", "d_raw", "chi2", "q_rot", "q_pos",
                                        "logdet", "scores", "raw_r", "raw_J", "whitened")}
        extras = {k: np.concatenate([o.extras[k] for o in outs]) for k in outs[0].extras}
        return EvalOut(**cat, extras=extras)

    def freeze_whitening(self, on: bool) -> None:
        """With ``on``, the next evaluation records its whitening operator (filter transition,
        gains, whitening factors) and later ones reuse it, so the cost is a fixed weighted
        least squares (what Gauss-Newton assumes) until this is called again."""
        self.freeze = on
        self._ops = {}

    def _evaluate_chunk(self, th: Theta, c: NDArray[np.int64], store: bool,
                        ci: int = 0) -> EvalOut:
        win = self.win
        tau, R_WM = win.tau[c], win.R_WM[c]
        h = np.diff(tau, axis=1)  # padded steps have h = 0
        inc, corr, dwf = self._imu_steps(th, c, tau, h)
        # Nominal trajectory; the start velocity is a fixed guess (a diffuse nuisance).
        Rbar, pbar, _ = compose(inc, h, R_WM[:, 0] @ th.R_MI,
                                win.p_WM[c, 0] + R_WM[:, 0] @ th.p_MI, win.v0[c],
                                th.g_mag * th.g_dir)
        res = self._residuals(th, R_WM, win.p_WM[c], Rbar, pbar)
        F = self._transition(inc, Rbar, h)
        gcols, g_in = self._gravity_inputs(th, h)
        # A frozen whitening (see freeze_whitening) needs no noise model here.
        frozen = self._ops.get(ci) if self.freeze else None
        noise = self._noise(th, h, R_WM) if (frozen is None or store) else None
        out = self._filter(th, c, ci, res, F, dwf, gcols, g_in, noise, frozen, store)
        return out

    def likelihoods(self, th: Theta, noises: list[NoiseModel]) -> list[tuple[Array, Array]]:
        """Per noise model, every window's chi2 and log det of its innovations (-2 log L is
        their sum) at the same parameters: the trajectory is integrated once, only the filter
        runs per model (without the Jacobian columns). Models of one kind (white or
        correlated mocap noise) run as one batch: the filter's cost is its loop over the
        samples, nearly the same for a larger batch."""
        win = self.win
        out = [(np.zeros(win.count), np.zeros(win.count)) for _ in noises]
        keep = self.noise
        try:
            for c in self.chunks:
                tau, R_WM = win.tau[c], win.R_WM[c]
                h = np.diff(tau, axis=1)
                inc, _, _ = self._imu_steps(th, c, tau, h, sensitivities=False)
                Rbar, pbar, _ = compose(inc, h, R_WM[:, 0] @ th.R_MI,
                                        win.p_WM[c, 0] + R_WM[:, 0] @ th.p_MI, win.v0[c],
                                        th.g_mag * th.g_dir)
                r = self._residuals(th, R_WM, win.p_WM[c], Rbar, pbar).r
                F = self._transition(inc, Rbar, h)
                for corr in (False, True):
                    group = [i for i, nz in enumerate(noises) if nz.mocap_correlated == corr]
                    if not group:
                        continue
                    stacked = []
                    for i in group:
                        self.noise = noises[i]
                        stacked.append(self._noise(th, h, R_WM))
                    noise = Noise(*(None if getattr(stacked[0], f) is None else
                                    np.concatenate([getattr(x, f) for x in stacked])
                                    for f in Noise.__dataclass_fields__))
                    K, n = len(group), len(c)
                    Phi = np.concatenate([F] * K)
                    if corr:
                        Phi = np.concatenate([Phi, np.zeros(Phi.shape[:2] + (15, 6))], -1)
                        Phi = np.concatenate([Phi, np.zeros(Phi.shape[:2] + (6, 21))], -2)
                        Phi[..., 15:21, 15:21] = noise.Fm
                    chi2, logdet = likelihood_pass(
                        np.concatenate([r] * K), Phi, noise,
                        np.concatenate([self.weights[c]] * K),
                        np.concatenate([win.mask[c]] * K))
                    for j, i in enumerate(group):
                        out[i][0][c] = chi2[j * n:(j + 1) * n]
                        out[i][1][c] = logdet[j * n:(j + 1) * n]
        finally:
            self.noise = keep
        return out

    def _imu_steps(self, th: Theta, c: NDArray[np.int64], tau: Array,
                   h: Array, sensitivities: bool = True
                   ) -> tuple[StepIncrements, Corrected, Array | None]:
        """Step increments of the corrected IMU and ``d(w, f)/dtheta`` at every step."""
        s, L, model = self.s, self.layout, self.model
        W, m, p = len(c), self.win.steps, L.dim
        # The clock effects move the samples in time: the drift stretches the IMU's time axis,
        # the accelerometer's lag shifts its samples against the gyro's.
        timing = Intrinsics(np.zeros(3), np.zeros(3), th.effects, th.t_mid)
        ut = imu_times(model, timing, s.u)
        lag = accel_lag(model, timing)
        # The lagging accelerometer is resampled at the gyro's sample times (a smooth function
        # of the lag), so the pieces stay aligned with the samples and the cost smooth in it.
        accel, accel_dot = s.accel, None
        if any(e.acts_on == "accel_lag" for e in model.units):
            at = hermite(ut, ut + lag)
            accel, accel_dot = at(s.accel), at.derivative(s.accel)
        rates = any(e.acts_on == "size" for e in model.units)  # terms in w and dw/dt
        # IMU signals on pieces between IMU samples (see preint.Pieces), corrected with each
        # window's knot biases.
        pc = pieces(ut, tau[:, :-1], tau[:, 1:], th.delta)  # nodes (W, m, 2n+1)
        intr = Intrinsics(th.knots[c, None, None, 0:3], th.knots[c, None, None, 3:6], th.effects,
                          th.t_mid)
        corr = correct(model, intr, *signals_at(s.gyro, accel, pc, pc.nodes - th.delta, rates),
                       sensitivities=False)
        inc = integrate_pieces(corr.w, corr.f, pc.hs)
        if not sensitivities:
            return inc, corr, None

        # Sensitivities at step midpoints.
        u_mid = 0.5 * (tau[:, :-1] + tau[:, 1:]) - th.delta
        intr_m = Intrinsics(th.knots[c, None, 0:3], th.knots[c, None, 3:6], th.effects, th.t_mid)
        cm = correct(model, intr_m, *signals_at(s.gyro, accel, hermite(ut, u_mid), u_mid, rates))
        dwf = self._buffer("dwf", (W, m, 6, p))  # d(w, f)/dtheta at each step
        dw, df = dwf[:, :, 0:3, :], dwf[:, :, 3:6, :]
        # Signals read at shifted times: d/dt of the signal, averaged over a step, is
        # (end - start) / h exactly (it telescopes, so the signal's noise does not add up).
        hinv = np.where(h > 0, 1.0 / np.where(h > 0, h, 1.0), 0.0)[..., None, None]
        w_rate = (corr.w[:, :, -1] - corr.w[:, :, 0])[..., None] * hinv
        f_rate = (corr.f[:, :, -1] - corr.f[:, :, 0])[..., None] * hinv
        for name, _ in L.blocks:
            sl = L.slice(name)
            kind = EFFECTS[name].acts_on if name in EFFECTS else name
            if name == "knot":
                dw[:, :, :, sl.start:sl.start + 3] = cm.dw["gyro_bias"]
                dw[:, :, :, sl.start + 3:sl.stop] = cm.dw["accel_bias"]
                df[:, :, :, sl.start:sl.start + 3] = cm.df["gyro_bias"]
                df[:, :, :, sl.start + 3:sl.stop] = cm.df["accel_bias"]
            elif kind == "clock":  # read at u = tau - delta: d/d delta = -d/du
                dw[:, :, :, sl] = -w_rate
                df[:, :, :, sl] = -f_rate
            elif kind == "clock_rate":  # samples moved by s (u - t_mid)
                lever = (u_mid - th.t_mid)[..., None, None]
                dw[:, :, :, sl] = -w_rate * lever
                df[:, :, :, sl] = -f_rate * lever
            elif kind == "accel_lag":  # accel resampled at x + lag: its step mean, exactly
                # A raw accel change acts like an accel bias of the opposite sign.
                a_mean = step_mean(pc(accel_dot), pc.hs, h)[..., None]
                dw[:, :, :, sl] = -cm.dw["accel_bias"] @ a_mean
                df[:, :, :, sl] = -cm.df["accel_bias"] @ a_mean
            elif kind == "size":  # terms in w and dw/dt, which vary within a step: its mean
                A = size_matrix(corr.w, corr.dw_du)
                d = np.zeros(A.shape[:-2] + (3, 6))
                d[..., 1, 0:3] = -A[..., 1, :]
                d[..., 2, 3:6] = -A[..., 2, :]
                mean = step_mean(d.reshape(d.shape[:-2] + (18,)), pc.hs, h).reshape(W, m, 3, 6)
                df[:, :, :, sl] = mean
                # f feeds the gyro through G: the accel-bias sensitivities carry that link.
                dw[:, :, :, sl] = cm.dw["accel_bias"] @ np.linalg.inv(cm.df["accel_bias"]) @ mean
            elif name in cm.dw:
                dw[:, :, :, sl] = cm.dw[name]
                df[:, :, :, sl] = cm.df[name]
        return inc, corr, dwf

    @staticmethod
    def _residuals(th: Theta, R_WM: Array, p_WM: Array, Rbar: Array, pbar: Array) -> _Residuals:
        """Residuals at every sample and the parts of their Jacobians not through S."""
        R_meas = R_WM @ th.R_MI
        p_meas = p_WM + np.einsum("wkij,j->wki", R_WM, th.p_MI)
        E = np.einsum("wkji,wkjl->wkil", Rbar, R_meas)
        r_rot = so3.log(E)
        r = np.concatenate([r_rot, p_meas - pbar], axis=-1)  # (W, m+1, 6)
        Jinv = so3.right_jacobian_inv(r_rot)
        Pm_rot = Jinv @ np.swapaxes(E, -1, -2)  # d r_rot / d (nominal attitude perturbation)
        return _Residuals(r, Jinv, Pm_rot, R_WM)

    def _transition(self, inc: StepIncrements, Rbar: Array, h: Array) -> Array:
        """Error-state transition per step (world-frame blocks need Rbar_k). The big array is
        reused between evaluations: its zero blocks never change."""
        W, m = h.shape
        Rk = Rbar[:, :-1]
        F = self._buffer("F", (W, m, 15, 15), identity_blocks=True)
        dRt = np.swapaxes(inc.dR, -1, -2)
        F[..., 0:3, 0:3] = dRt
        F[..., 0:3, 9:12] = -dRt @ inc.A
        F[..., 3:6, 0:3] = -Rk @ so3.hat(inc.dp)
        F[..., 3:6, 6:9] = np.eye(3) * h[..., None, None]
        F[..., 3:6, 9:12] = Rk @ inc.D
        F[..., 3:6, 12:15] = -Rk @ inc.C
        F[..., 6:9, 0:3] = -Rk @ so3.hat(inc.dv)
        F[..., 6:9, 9:12] = Rk @ inc.B
        F[..., 6:9, 12:15] = -Rk @ inc.A
        return F

    def _gravity_inputs(self, th: Theta, h: Array) -> tuple[list[int], Array]:
        """Columns and per-step inputs of the gravity parameters (velocity and position)."""
        L = self.layout
        W, m = h.shape
        # Parameter inputs: a parameter acts like a bias of -dw/dtheta, -df/dtheta; gravity
        # enters the velocity and position directly.
        gcols = list(range(L.slice("gravity").start, L.slice("gravity").stop))
        dg = th.g_mag * th.g_basis  # (3, 2)
        if L.has("gravity_magnitude"):
            gcols.append(L.slice("gravity_magnitude").start)
            dg = np.concatenate([dg, th.g_dir[:, None]], axis=1)
        g_in = np.empty((W, m, 6, len(gcols)))
        g_in[..., 0:3, :] = 0.5 * (h**2)[..., None, None] * dg
        g_in[..., 3:6, :] = h[..., None, None] * dg
        return gcols, g_in

    def _noise(self, th: Theta, h: Array, R_WM: Array) -> Noise:
        """Process noise of every step and mocap noise of every sample (see
        :func:`~mocap_calib.core.position.kalman.filter_noise`)."""
        # d p_meas / d (attitude noise in the I frame): the lever arm moves the position.
        return filter_noise(self.noise, R_WM @ so3.hat(th.p_MI) @ th.R_MI, h)

    def _filter(self, th: Theta, c: NDArray[np.int64], ci: int, res: _Residuals, F: Array,
                dwf: Array, gcols: list[int], g_in: Array, noise: Noise | None,
                frozen: dict[str, Array] | None, store: bool) -> EvalOut:
        """Sequential pass over the steps: sensitivities S, Kalman whitening, Gram matrix.

        The filter state is the error state (attitude, position, velocity, bias deviations:
        15) plus, with correlated mocap noise, its six states; ``X`` carries the filter's
        estimate of the state for every column of ``[J | r]`` at once.
        """
        L, mask = self.layout, self.win.mask[c]
        W, m, p = len(c), self.win.steps, L.dim
        r, Jinv, Pm_rot, R_WM = res.r, res.Jinv, res.Pm_rot, res.R_WM
        corr = self.noise.mocap_correlated
        ns = 21 if corr else 15
        wts = self.weights[c]
        weighted = wts < 1.0
        rs, ts = L.slice("rotation"), L.slice("translation")
        S = np.zeros((W, 9, p))
        S[:, 0:3, rs] = np.eye(3)
        S[:, 3:6, ts] = R_WM[:, 0]
        P = np.zeros((W, ns, ns))
        for i, d in enumerate(DIFFUSE):
            P[:, 3 * i:3 * i + 3, 3 * i:3 * i + 3] = d**2 * np.eye(3)
        if corr and noise is not None:
            P[:, 15:, 15:] = noise.Pm0
        Phi = self._transition_full(F, noise) if frozen is None else frozen["F"]
        X = np.zeros((W, ns, p + 1))
        # A frozen whitening operator (transition for the filter mean, gains, whitening) makes
        # the cost an exact weighted least squares in the parameters while LM runs on it.
        record = self.freeze and frozen is None
        if record:
            rec_Li = np.zeros((W, m + 1, 6, 6))
            rec_K = np.zeros((W, m + 1, ns, 6))
        acc = Accumulator(W, m, p, store, self._score_blocks(m) if self.collect_scores else None)
        N = np.zeros((W, 6, p + 1))
        for k in range(m + 1):
            if k > 0:
                Fk = F[:, k - 1]
                S = Fk[:, 0:9, 0:9] @ S - Fk[:, 0:9, 9:15] @ dwf[:, k - 1]
                S[:, 3:9, gcols] += g_in[:, k - 1]
                X = Phi[:, k - 1] @ X
                if frozen is None:
                    P = predict_covariance(P, Phi[:, k - 1], noise, k - 1)
            # Residual Jacobian: direct part minus the nominal's sensitivity.
            N[:, 0:3, :p] = -(Pm_rot[:, k] @ S[:, 0:3, :])
            N[:, 0:3, rs] += Jinv[:, k]
            N[:, 3:6, :p] = -S[:, 3:6, :]
            N[:, 3:6, ts] += R_WM[:, k]
            N[:, :, p] = r[:, k]
            if store:
                acc.raw_J[:, k] = N[:, :, :p]
            N -= X[:, 0:6, :] + X[:, 15:21, :] if corr else X[:, 0:6, :]
            ok = mask[:, k]
            if frozen is not None:
                Li = frozen["Li"][:, k]
            else:
                PHt = P[:, :, 0:6] + P[:, :, 15:21] if corr else P[:, :, 0:6]  # (W, ns, 6)
                HPHt = PHt[:, 0:6] + PHt[:, 15:21] if corr else PHt[:, 0:6]
                Sk = HPHt + noise.Rn[:, k] / wts[:, k, None, None]
                Li = np.linalg.inv(np.linalg.cholesky(Sk))
            Nw = Li @ N
            Nw[~ok] = 0.0
            acc.add(k, N, Nw, Li, ok)
            wk = weighted[:, k]
            if frozen is None and np.any(wk):
                # The robust weight's own test needs the innovation against the unweighted noise.
                Sraw = HPHt[wk] + noise.Rn[wk, k]
                acc.d_raw[wk, k] = np.linalg.norm(
                    np.linalg.solve(np.linalg.cholesky(Sraw), N[wk, :, p:]), axis=(1, 2))
            if frozen is not None:
                X += frozen["K"][:, k] @ N
                continue
            K = PHt @ (np.swapaxes(Li, 1, 2) @ Li)  # (W, ns, 6)
            K[~ok] = 0.0
            X += K @ N
            P -= K @ np.swapaxes(PHt, 1, 2)
            P = 0.5 * (P + np.swapaxes(P, 1, 2))
            if record:
                rec_Li[:, k] = Li
                rec_K[:, k] = K
        if record:
            self._ops[ci] = {"F": Phi.copy(), "Li": rec_Li, "K": rec_K}
        extras = {}
        if store:  # the state-space model itself, for tests against a dense covariance
            extras = {"F": F.copy(), "q_diag": noise.q_diag, "q_pv": noise.q_pv, "Rn": noise.Rn,
                      "weights": wts.copy()}
            if corr:
                extras.update(Fm=noise.Fm, Qm=noise.Qm, Pm0=noise.Pm0)
        return acc.result(mask, r if store else None, extras)

    def _transition_full(self, F: Array, noise: Noise | None) -> Array:
        """The filter's transition: the error state's, and the correlated mocap noise's."""
        if noise is None or noise.Fm is None:
            return F
        W, m = F.shape[:2]
        Phi = self._buffer("Phi", (W, m, 21, 21))
        Phi[..., 0:15, 0:15] = F
        Phi[..., 15:21, 15:21] = noise.Fm
        return Phi

    def _score_blocks(self, m: int) -> NDArray[np.int64]:
        """Block index of every sample of a window: blocks of about ``SCORE_BLOCK_S``."""
        rate = 1.0 / float(np.median(np.diff(self.win.tau[0][self.win.mask[0]])))
        per = max(1, int(round(SCORE_BLOCK_S * rate)))
        return np.arange(m + 1) // per

    def _buffer(self, name: str, shape: tuple[int, ...], identity_blocks: bool = False) -> Array:
        """A reusable array: blocks not written by the caller keep their initial values. Chunks
        of fewer windows get a leading slice, so that alternating chunk sizes do not allocate
        (and fill) a new array at every call."""
        buffers = self._local.__dict__.setdefault("buffers", {})
        buf = buffers.get(name)
        if buf is None or buf.shape[1:] != shape[1:] or buf.shape[0] < shape[0]:
            buf = np.zeros(shape)
            if identity_blocks:
                for a, b in ((3, 3), (6, 6)):
                    buf[..., a:a + 3, b:b + 3] = np.eye(3)
                buf[..., 9:15, 9:15] = np.eye(6)
            buffers[name] = buf
        return buf[:shape[0]]

    # ------------------------------------------------------------------ noise and weights
    def mocap_noise_scale(self, out: EvalOut, skip: int = 5) -> tuple[float, float]:
        """Robust estimate of how much larger (variance) the mocap attitude / position noise is
        than modelled: median whitened innovation over the median of chi^2_3.

        Uses inlier samples past each window's first ``skip`` (where the diffuse start state
        still absorbs the innovations)."""
        use = self.win.mask & (self.weights >= 1.0)
        use[:, :skip] = False
        if use.sum() < 50:
            return 1.0, 1.0
        med = float(sps.chi2.median(3))
        return (float(np.median(out.q_rot[use])) / med, float(np.median(out.q_pos[use])) / med)

    def scale_mocap_noise(self, s_rot: float, s_pos: float) -> None:
        """Multiply the mocap noise variances (attitude, position)."""
        nz = self.noise
        self.noise = replace(nz, mocap_rotation_sigma=nz.mocap_rotation_sigma * np.sqrt(s_rot),
                             mocap_position_sigma=nz.mocap_position_sigma * np.sqrt(s_pos))

    # ------------------------------------------------------------------ robust weights
    def update_weights(self, d_raw: Array, c: float = ROBUST_C) -> float:
        """Redescending weights from the unweighted innovation norms; returns the max change."""
        w = np.where(d_raw <= c, 1.0, (c / np.maximum(d_raw, 1e-12)) ** 2)
        w = np.maximum(w, 1e-6)
        w[~self.win.mask] = 1.0
        change = float(np.max(np.abs(w - self.weights))) if w.size else 0.0
        self.weights = w
        return change


def compress(gram: Array) -> tuple[Array, Array]:
    """From a window's Gram matrix of ``[J | r]`` to an equivalent ``p + 1`` row factor.

    Returns ``(e, H)`` with ``|e + H delta|^2 == |r + J delta|^2`` for every ``delta``.
    """
    p = gram.shape[-1] - 1
    scale = np.sqrt(np.maximum(np.diagonal(gram, axis1=-2, axis2=-1), 1e-300))
    scale[..., :p] = np.where(scale[..., :p] > 1e-150, scale[..., :p], 1.0)
    gs = gram / scale[..., :, None] / scale[..., None, :]
    gs = gs + 1e-13 * np.eye(p + 1)
    Lc = np.linalg.cholesky(gs)
    U = np.swapaxes(Lc, -1, -2) * scale[..., None, :]
    return U[..., :, p], U[..., :, :p]



