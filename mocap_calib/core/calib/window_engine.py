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

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import stats as sps

from mocap_calib.core.calib.session import PreparedSession
from mocap_calib.core.calib.windows import (  # noqa: F401  (re-exported)
    EvalOut,
    Layout,
    Theta,
    Windows,
    layout_for,
    make_windows,
)
from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.imu_model import Corrected, Intrinsics, correct
from mocap_calib.core.model.preint import (
    StepIncrements,
    compose,
    hermite,
    integrate_pieces,
    pieces,
)
from mocap_calib.core.model.types import NoiseModel

Array = NDArray[np.float64]

#: Robust kernel threshold on a sample's whitened 6-D innovation norm (chi, 6 dof, 99.9%).
ROBUST_C = float(np.sqrt(sps.chi2.ppf(0.999, 6)))
#: Diffuse prior of a window's start state: attitude (rad), position (m), velocity (m/s).
DIFFUSE = (1.0, 1.0, 0.5)


@dataclass(frozen=True)
class _Residuals:
    r: Array  # (W, m+1, 6) attitude and position residuals
    Jinv: Array  # (W, m+1, 3, 3) right-Jacobian inverse of the attitude residual
    Pm_rot: Array  # (W, m+1, 3, 3) d r_rot / d (nominal attitude perturbation)
    R_WM: Array  # (W, m+1, 3, 3)


@dataclass(frozen=True)
class _Noise:
    q_diag: Array  # (W, m, 15) diagonal process noise per step
    q_pv: Array  # (W, m) position-velocity cross term
    Rn: Array  # (W, m+1, 6, 6) mocap noise of each residual


class PositionProblem:
    """Evaluates the window factors for all windows at once.

    Args:
        s: prepared session.
        model: active effects.
        noise: noise densities.
        windows: from :func:`make_windows`.
        chunk_steps: windows are processed in chunks of about this many samples (memory).
    """

    def __init__(self, s: PreparedSession, model: Model, noise: NoiseModel, windows: Windows,
                 chunk_steps: int = 40_000) -> None:
        self.s = s
        self.model = model
        self.noise = noise
        self.win = windows
        self.layout = layout_for(model)
        per = max(1, chunk_steps // max(1, windows.steps))
        self.chunks = [np.arange(i, min(i + per, windows.count))
                       for i in range(0, windows.count, per)]
        self.weights = np.ones(windows.idx.shape)
        self._buffers: dict[str, Array] = {}
        self.freeze = False
        self._ops: dict[int, dict[str, Array]] = {}

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, th: Theta, store: bool = False) -> EvalOut:
        outs = [self._evaluate_chunk(th, c, store, ci) for ci, c in enumerate(self.chunks)]
        cat = {f: (np.concatenate([getattr(o, f) for o in outs]) if getattr(outs[0], f) is not None
                   else None) for f in ("gram", "innovation", "d_raw", "chi2", "q_rot", "q_pos",
                                        "raw_r", "raw_J", "whitened")}
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

    def _imu_steps(self, th: Theta, c: NDArray[np.int64], tau: Array,
                   h: Array) -> tuple[StepIncrements, Corrected, Array]:
        """Step increments of the corrected IMU and ``d(w, f)/dtheta`` at every step."""
        s, L = self.s, self.layout
        W, m, p = len(c), self.win.steps, L.dim
        # IMU signals on pieces between IMU samples (see preint.Pieces), corrected with each
        # window's knot biases.
        pc = pieces(s.u, tau[:, :-1], tau[:, 1:], th.delta)  # nodes (W, m, 2n+1)
        intr = Intrinsics(th.knots[c, None, None, 0:3], th.knots[c, None, None, 3:6], th.effects,
                          th.t_mid)
        corr = correct(self.model, intr, pc(s.gyro), pc(s.accel), pc.nodes - th.delta,
                       sensitivities=False)
        inc = integrate_pieces(corr.w, corr.f, pc.hs)

        # Sensitivities at step midpoints.
        u_mid = 0.5 * (tau[:, :-1] + tau[:, 1:]) - th.delta
        ipm = hermite(s.u, u_mid)
        intr_m = Intrinsics(th.knots[c, None, 0:3], th.knots[c, None, 3:6], th.effects, th.t_mid)
        cm = correct(self.model, intr_m, ipm(s.gyro), ipm(s.accel), u_mid)
        dwf = self._buffer("dwf", (W, m, 6, p))  # d(w, f)/dtheta at each step
        dw, df = dwf[:, :, 0:3, :], dwf[:, :, 3:6, :]
        for name, _ in L.blocks:
            sl = L.slice(name)
            if name == "knot":
                dw[:, :, :, sl.start:sl.start + 3] = cm.dw["gyro_bias"]
                dw[:, :, :, sl.start + 3:sl.stop] = cm.dw["accel_bias"]
                df[:, :, :, sl.start:sl.start + 3] = cm.df["gyro_bias"]
                df[:, :, :, sl.start + 3:sl.stop] = cm.df["accel_bias"]
            elif name == "time_offset":
                # Signals are read at u = tau - delta: d/d delta = -d/du. Averaged over the step
                # the integral of the interpolant's derivative is (end - start) / h, exactly:
                # it telescopes, so the signal's noise does not add up along the window.
                hinv = np.where(h > 0, 1.0 / np.where(h > 0, h, 1.0), 0.0)[..., None, None]
                dw[:, :, :, sl] = -(corr.w[:, :, -1] - corr.w[:, :, 0])[..., None] * hinv
                df[:, :, :, sl] = -(corr.f[:, :, -1] - corr.f[:, :, 0])[..., None] * hinv
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

    def _noise(self, th: Theta, h: Array, R_WM: Array) -> _Noise:
        """Process noise of every step and mocap noise of every sample."""
        nz = self.noise
        W, m = h.shape
        # Process noise per step (isotropic densities, so frame rotations drop out).
        sg2 = nz.gyroscope_noise_density**2
        sa2 = nz.accelerometer_noise_density**2
        q_diag = np.empty((W, m, 15))
        q_diag[..., 0:3] = (sg2 * h)[..., None]
        q_diag[..., 3:6] = (sa2 * h**3 / 3.0)[..., None]
        q_diag[..., 6:9] = (sa2 * h)[..., None]
        q_diag[..., 9:12] = (nz.gyroscope_random_walk**2 * h)[..., None]
        q_diag[..., 12:15] = (nz.accelerometer_random_walk**2 * h)[..., None]
        q_pv = sa2 * h**2 / 2.0

        # Mocap noise of each residual: rotation noise in the marker frame moves p_meas too.
        sr2 = nz.mocap_rotation_sigma**2
        lev = R_WM @ so3.hat(th.p_MI)  # d p_meas / d (marker attitude noise) = -lev
        Rn = np.empty((W, m + 1, 6, 6))
        Rn[..., 0:3, 0:3] = sr2 * np.eye(3)
        Rn[..., 0:3, 3:6] = -sr2 * th.R_MI.T @ np.swapaxes(lev, -1, -2)
        Rn[..., 3:6, 0:3] = np.swapaxes(Rn[..., 0:3, 3:6], -1, -2)
        Rn[..., 3:6, 3:6] = (nz.mocap_position_sigma**2 * np.eye(3)
                             + sr2 * lev @ np.swapaxes(lev, -1, -2))
        return _Noise(q_diag, q_pv, Rn)

    def _filter(self, th: Theta, c: NDArray[np.int64], ci: int, res: _Residuals, F: Array,
                dwf: Array, gcols: list[int], g_in: Array, noise: _Noise | None,
                frozen: dict[str, Array] | None, store: bool) -> EvalOut:
        """Sequential pass over the steps: sensitivities S, Kalman whitening, Gram matrix."""
        L, mask = self.layout, self.win.mask[c]
        W, m, p = len(c), self.win.steps, L.dim
        r, Jinv, Pm_rot, R_WM = res.r, res.Jinv, res.Pm_rot, res.R_WM
        q_diag, q_pv, Rn = (noise.q_diag, noise.q_pv, noise.Rn) if noise else (None, None, None)
        wts = self.weights[c]
        weighted = wts < 1.0

        # --- Sequential pass: sensitivities S, Kalman whitening, Gram accumulation.
        rs, ts = L.slice("rotation"), L.slice("translation")
        S = np.zeros((W, 9, p))
        S[:, 0:3, rs] = np.eye(3)
        S[:, 3:6, ts] = R_WM[:, 0]
        P = np.zeros((W, 15, 15))
        P[:, 0:3, 0:3] = DIFFUSE[0] ** 2 * np.eye(3)
        P[:, 3:6, 3:6] = DIFFUSE[1] ** 2 * np.eye(3)
        P[:, 6:9, 6:9] = DIFFUSE[2] ** 2 * np.eye(3)
        X = np.zeros((W, 15, p + 1))
        # A frozen whitening operator (transition for the filter mean, gains, whitening) makes
        # the cost an exact weighted least squares in the parameters while LM runs on it.
        record = self.freeze and frozen is None
        if record:
            rec_F = F.copy()
            rec_Li = np.zeros((W, m + 1, 6, 6))
            rec_K = np.zeros((W, m + 1, 15, 6))
        gram = np.zeros((W, p + 1, p + 1))
        innov = np.zeros((W, m + 1, 6))
        d_raw = np.zeros((W, m + 1))
        q_rot = np.zeros((W, m + 1))
        q_pos = np.zeros((W, m + 1))
        chi2 = np.zeros(W)
        raw_J = np.zeros((W, m + 1, 6, p)) if store else None
        whitened = np.zeros((W, m + 1, 6, p + 1)) if store else None
        N = np.zeros((W, 6, p + 1))
        i15 = np.arange(15)
        i3 = np.arange(3)
        for k in range(m + 1):
            if k > 0:
                Fk = F[:, k - 1]
                S = Fk[:, 0:9, 0:9] @ S - Fk[:, 0:9, 9:15] @ dwf[:, k - 1]
                S[:, 3:9, gcols] += g_in[:, k - 1]
                if frozen is not None:
                    X = frozen["F"][:, k - 1] @ X
                else:
                    X = Fk @ X
                    P = Fk @ P @ np.swapaxes(Fk, 1, 2)
                    P[:, i15, i15] += q_diag[:, k - 1]
                    P[:, 3 + i3, 6 + i3] += q_pv[:, k - 1, None]
                    P[:, 6 + i3, 3 + i3] += q_pv[:, k - 1, None]
            # Residual Jacobian: direct part minus the nominal's sensitivity.
            N[:, 0:3, :p] = -(Pm_rot[:, k] @ S[:, 0:3, :])
            N[:, 0:3, rs] += Jinv[:, k]
            N[:, 3:6, :p] = -S[:, 3:6, :]
            N[:, 3:6, ts] += R_WM[:, k]
            N[:, :, p] = r[:, k]
            if store:
                raw_J[:, k] = N[:, :, :p]
            N -= X[:, 0:6, :]
            ok = mask[:, k]
            if frozen is not None:
                Li = frozen["Li"][:, k]
            else:
                Sinn = P[:, 0:6, 0:6] + Rn[:, k] / wts[:, k, None, None]
                Li = np.linalg.inv(np.linalg.cholesky(Sinn))
            Nw = Li @ N
            Nw[~ok] = 0.0
            gram += np.swapaxes(Nw, 1, 2) @ Nw
            chi2 += np.sum(Nw[:, :, p] ** 2, axis=1)
            innov[:, k] = N[:, :, p]
            d_raw[:, k] = np.linalg.norm(Nw[:, :, p], axis=1)
            # L is lower-triangular: the first three whitened components involve only the
            # attitude innovation and its own covariance block.
            q_rot[:, k] = np.sum(Nw[:, 0:3, p] ** 2, axis=1)
            q_pos[:, k] = np.sum(Nw[:, 3:6, p] ** 2, axis=1)
            wk = weighted[:, k]
            if frozen is None and np.any(wk):
                # The robust weight's own test needs the innovation against the unweighted noise.
                Sraw = P[wk, 0:6, 0:6] + Rn[wk, k]
                d_raw[wk, k] = np.linalg.norm(
                    np.linalg.solve(np.linalg.cholesky(Sraw), N[wk, :, p:]), axis=(1, 2))
            if store:
                whitened[:, k] = Nw
            if frozen is not None:
                X += frozen["K"][:, k] @ N
                continue
            K = P[:, :, 0:6] @ (np.swapaxes(Li, 1, 2) @ Li)  # (W, 15, 6)
            K[~ok] = 0.0
            X += K @ N
            P -= K @ P[:, 0:6, :]
            P = 0.5 * (P + np.swapaxes(P, 1, 2))
            if record:
                rec_Li[:, k] = Li
                rec_K[:, k] = K
        if record:
            self._ops[ci] = {"F": rec_F, "Li": rec_Li, "K": rec_K}
        d_raw[~mask] = 0.0
        innov[~mask] = 0.0
        extras = {}
        if store:  # the state-space model itself, for tests against a dense covariance
            extras = {"F": F.copy(), "q_diag": q_diag, "q_pv": q_pv, "Rn": Rn,
                      "weights": wts.copy()}
        return EvalOut(gram, innov, d_raw, chi2, q_rot, q_pos, r if store else None, raw_J,
                       whitened, extras)

    def _buffer(self, name: str, shape: tuple[int, ...], identity_blocks: bool = False) -> Array:
        """A reusable array: blocks not written by the caller keep their initial values."""
        buf = self._buffers.get(name)
        if buf is None or buf.shape != shape:
            buf = np.zeros(shape)
            if identity_blocks:
                for a, b in ((3, 3), (6, 6)):
                    buf[..., a:a + 3, b:b + 3] = np.eye(3)
                buf[..., 9:15, 9:15] = np.eye(6)
            self._buffers[name] = buf
        return buf

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



