"""Position factors: whole windows of mocap poses against the IMU-propagated trajectory.

A window is a gap-free stretch of mocap samples (a few seconds). From the window's first mocap
pose the IMU, corrected by the current model, is integrated forward (RK4 between samples, see
:mod:`mocap_calib.core.model.preint`) and compared with every mocap pose in the window:

    r_k = [ Log(R_bar_k^T R_WM,k R_MI) ;  p_WM,k - (p_bar_k - R_bar_k R_MI^T p_MI) ]

(the measured marker pose against the one the IMU trajectory predicts: the lever arm turns
with the filter's attitude, not with the measured one, whose noise would otherwise enter the
lever arm's own regressor and pass for rotation it can learn from).

The start velocity and pose of each window are nuisance (diffuse) and the IMU noise, the bias
random walk within the window and the mocap noise are all in the noise model: a Kalman filter
over the window's error state (attitude, position, velocity, gyro and accel bias deviations)
turns the correlated residuals into white innovations, and the same filter applied to the
residual Jacobian gives the whitened Jacobian. This is the exact Gaussian likelihood of the
window, computed in time linear in its length. Each window's whitened system is compressed to
its Gram matrix's Cholesky factor, so the factor GTSAM sees has ``p + 1`` rows.

The IMU signals, their correction and the residuals are numpy arrays over a chunk of windows
(windows x steps); the loops over the samples (RK4 on the pieces, the filter) are compiled and
release the GIL, so the chunks run on threads (:mod:`mocap_calib.core.position.threads`). Memory
is bounded by the chunk size, whatever the session's length: a frozen whitening keeps only the
steps' increments and attitudes it was built from.
"""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.effects import EFFECTS, GRAVITY_MAGNITUDE, Model
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
from mocap_calib.core.model.stats import chi2_median, chi2_ppf
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.kalman import (
    Whitening,
    empty_output,
    filter_pass,
    lever_matrix,
    likelihood_pass,
    noise_params,
    output_slice,
    residual_rows,
    signals_at,
    step_mean,
)
from mocap_calib.core.position.motion import motion_signals
from mocap_calib.core.position.threads import split_windows
from mocap_calib.core.position.windows import (  # noqa: F401  (re-exported)
    EvalOut,
    Layout,
    Seed,
    Theta,
    Windows,
    layout_for,
    make_windows,
)
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.threads import chunk_pool, map_blocks

Array = NDArray[np.float64]

#: Robust kernel threshold on a sample's whitened 6-D innovation norm (chi, 6 dof, 99.9%).
ROBUST_C = float(np.sqrt(chi2_ppf(0.999, 6)))
#: Length (s) of the blocks of consecutive samples whose scores the sandwich covariance sums:
#: longer than the correlation of real mocap noise, short enough for many blocks per session.
SCORE_BLOCK_S = 1.0
#: Jacobian columns (and the residual) a chunk's ``chunk_steps`` are sized for: the base
#: model with a clock offset (rotation, translation, gravity, clock, knot).
CHUNK_COLUMNS = 16


class PositionProblem:
    """Evaluates the window factors for all windows at once.

    Args:
        s: prepared session.
        model: active effects.
        noise: noise densities.
        windows: from :func:`make_windows`.
        chunk_steps: windows are processed in chunks of about this many samples for the
            calibration's usual :data:`CHUNK_COLUMNS` columns (fewer with more): their arrays
            (a few kB a sample, growing with the columns) are what an evaluation holds in
            memory at a time.
        split: split into two chunks at least (for the threads); off for small problems
            evaluated many times, where one batch costs less than two.
    """

    def __init__(self, s: PreparedSession, model: Model, noise: NoiseModel, windows: Windows,
                 chunk_steps: int = 8_000, split: bool = True) -> None:
        self.s = s
        self.model = model
        self.noise = noise
        self.win = windows
        self.layout = layout_for(model)
        # The sensitivities grow with the columns: the effect tests' model (50+ columns)
        # would hold 3-4x the memory per chunk of the base model's.
        steps = max(500, chunk_steps * CHUNK_COLUMNS // (self.layout.dim + 1))
        self.chunks = split_windows(windows.count, windows.steps, steps, split)
        self.weights = np.ones(windows.idx.shape)
        self._local = threading.local()  # per-thread work buffers
        self.freeze = False
        self.seed: Seed | None = None  # an evaluation of these windows to reuse (see Seed)
        self.collect_scores = False  # per-block scores in unfrozen evaluations (sandwich)
        # Mocap noise variance multipliers per axis: attitude x, y, z (IMU frame), position
        # x, y, z (world frame), on top of the noise model's two levels.
        self.mocap_axis_scale = np.ones(6)
        self._ops: dict[int, Whitening] = {}
        self._motion: tuple[Array, Array] | None = None  # see motion_samples
        self._motion_lock = threading.Lock()
        self._lag_cache: dict[tuple[str, float, float, float], Array] = {}
        # The trajectory of every chunk at the parameters of the last likelihoods call: a
        # noise search asks for many noise models at the same parameters, batch after batch.
        self._paths: tuple[Theta | None, dict[int, tuple[Array, ...]]] = (None, {})

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, th: Theta, store: bool = False, integral: bool = False) -> EvalOut:
        """Every window's whitened system and statistics at ``th`` (with ``store``: also the
        raw residuals and Jacobians and the filter's model, for tests; with ``integral`` the
        windows' bias integrals). Chunks write their windows' slices of one set of arrays: an
        evaluation holds nothing twice."""
        W, m1 = self.win.mask.shape
        n_blocks = int(self._score_blocks(m1 - 1)[-1]) + 1 if self.collect_scores else None
        if self.seed is not None and not (store or integral or self.freeze):
            hit = self.seed.reuse(th, self.noise, self.weights, self.mocap_axis_scale, n_blocks)
            if hit is not None:
                return hit
        out = empty_output(W, m1, self.layout.dim, n_blocks, store, integral)
        pool = chunk_pool()
        jobs = list(enumerate(self.chunks))
        if len(jobs) > 1 and pool is not None:
            parts = list(pool.map(lambda job: self._evaluate_chunk(th, job[1], out, job[0]),
                                  jobs))
        else:
            parts = [self._evaluate_chunk(th, c, out, ci) for ci, c in jobs]
        if store:
            out.extras.update({k: np.concatenate([x[k] for x in parts]) for k in parts[0]})
        return out

    @property
    def motion(self) -> tuple[Array, Array] | None:
        """The motion signals, once an evaluation has computed them (see motion_samples)."""
        return self._motion

    def use_seed(self, seed: Seed | None) -> None:
        """Evaluate as the problem ``seed`` comes from did: its evaluation where the parameters
        are as they were, the session's motion signals (whose band follows the first window's
        rate) always."""
        self.seed = seed
        if seed is not None and seed.motion is not None:
            self._motion = seed.motion

    def freeze_whitening(self, on: bool) -> None:
        """With ``on``, the next evaluation records its whitening operator (filter transition,
        gains, whitening factors) and later ones reuse it, so the cost is a fixed weighted
        least squares (what Gauss-Newton assumes) until this is called again. The record is
        what the operator is built from (the steps' increments, the start attitudes, noise,
        weights; the increments in single precision): a replay runs the filter on it
        again."""
        self.freeze = on
        self._ops = {}

    def _evaluate_chunk(self, th: Theta, c: NDArray[np.int64], out: EvalOut,
                        ci: int = 0) -> dict[str, Array]:
        """Windows ``c`` (consecutive) into their slice of ``out``; returns the filter's model
        when ``out`` stores it."""
        win = self.win
        tau, (R_WM, p_WM) = win.tau[c], win.poses(c)
        h = np.diff(tau, axis=1)  # padded steps have h = 0
        inc, _, dwf = self._imu_steps(th, c, tau, h)
        # Nominal trajectory; the start velocity is a fixed guess (a diffuse nuisance).
        R0 = R_WM[:, 0] @ th.R_MI
        Rbar, pbar, _ = compose(inc, h, R0, p_WM[:, 0] + R_WM[:, 0] @ th.p_MI, win.v0[c],
                                th.g_mag * th.g_dir)
        rows = residual_rows(th.R_MI, th.p_MI, R_WM, p_WM, Rbar, pbar)
        current = self._whitening(th, c, inc.pack(), R0)
        # A frozen whitening (see freeze_whitening) is the recorded one; the first evaluation
        # after freezing records its own. The record keeps the increments in single precision
        # (it is held for the whole session while the cost is frozen: 73 MB at 60 min, half
        # the double-precision record),
        # and every evaluation of the frozen cost, the first included, replays the record, so
        # that the cost is one fixed function (its weighting rounded at 1e-7, the residuals
        # and Jacobians in double precision).
        op = self._ops.get(ci) if self.freeze else None
        if self.freeze and op is None:
            op = replace(current, inc=current.inc.astype(np.float32))
            self._ops[ci] = op
        L = self.layout
        gcols, dg = self._gravity_inputs(th)
        blocks = self._score_blocks(win.steps) if self.collect_scores else None
        part = output_slice(out, slice(int(c[0]), int(c[-1]) + 1))
        filter_pass(h, win.mask[c], current, Rbar, op, rows, dwf, dg, gcols,
                    L.slice("rotation").start, L.slice("translation").start, blocks, part)
        return part.extras

    def _whitening(self, th: Theta, c: NDArray[np.int64], inc: Array, R0: Array,
                   noise: NoiseModel | None = None) -> Whitening:
        """The filter of windows ``c`` at ``th`` (under ``noise``, default the problem's)."""
        par = noise_params(self.noise if noise is None else noise, self.mocap_axis_scale)
        return Whitening(inc, R0, par, lever_matrix(th.R_MI, th.p_MI), self.weights[c])

    def spread(self, th: Theta, max_windows: int, every: int = 1) -> tuple[PositionProblem, Theta]:
        """This problem on at most ``max_windows`` windows spread evenly over the session
        (every ``every``-th sample of each), with its noise, weights and mocap levels, and
        ``th`` cut to them: what the noise-level likelihoods are evaluated on."""
        W = self.win.count
        which = np.unique(np.linspace(0, W - 1, min(W, max_windows)).round().astype(np.int64))
        sub = PositionProblem(self.s, self.model, self.noise,
                              self.win.subset(which).decimate(every), split=False)
        sub.mocap_axis_scale = self.mocap_axis_scale.copy()
        sub._motion = self._motion
        sub.weights = self.weights[which][:, ::every].copy() if every > 1 else self.weights[which]
        return sub, replace(th, knots=th.knots[which])

    def likelihoods(self, th: Theta, noises: list[NoiseModel]) -> list[tuple[Array, Array]]:
        """Per noise model, every window's chi2 and log det of its innovations (-2 log L is
        their sum) at the same parameters: the trajectory is integrated once, only the filter
        (without the Jacobian columns) runs per model."""
        win = self.win
        out = [(np.zeros(win.count), np.zeros(win.count)) for _ in noises]

        if self._paths[0] is not th:
            self._paths = (th, {})
        paths = self._paths[1]

        def chunk(c: NDArray[np.int64]) -> None:  # writes only its windows' entries
            key = int(c[0])
            if key not in paths:
                tau, (R_WM, p_WM) = win.tau[c], win.poses(c)
                h = np.diff(tau, axis=1)
                inc, _, _ = self._imu_steps(th, c, tau, h, sensitivities=False)
                R0 = R_WM[:, 0] @ th.R_MI
                Rbar, pbar, _ = compose(inc, h, R0, p_WM[:, 0] + R_WM[:, 0] @ th.p_MI,
                                        win.v0[c], th.g_mag * th.g_dir)
                r = residual_rows(th.R_MI, th.p_MI, R_WM, p_WM, Rbar, pbar,
                                  jacobians=False).r
                paths[key] = (h, R0, Rbar, r, inc.pack())
            h, R0, Rbar, r, packed = paths[key]

            def model(i: int) -> None:
                wh = self._whitening(th, c, packed, R0, noises[i])
                out[i][0][c], out[i][1][c] = likelihood_pass(h, win.mask[c], wh, Rbar, r)

            # On the threads when this chunk is the problem's only one (the noise searches'
            # few windows); in a chunk's own thread, one model after the other.
            map_blocks(model, range(len(noises)))

        pool = chunk_pool()
        if len(self.chunks) > 1 and pool is not None:
            list(pool.map(chunk, self.chunks))
        else:
            for c in self.chunks:
                chunk(c)
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
        accel = s.accel
        if model.has_kind("accel_lag"):
            accel = self._lagged("accel", ut, lag)
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
        # (end - start) / h exactly (it telescopes); of the motion's signal, not the samples'
        # (see motion.py).
        hinv = np.where(h > 0, 1.0 / np.where(h > 0, h, 1.0), 0.0)[..., None, None]
        w_rate = f_rate = np.zeros((W, m, 3, 1))
        if model.has_kind("clock") or model.has_kind("clock_rate"):
            w_end, f_end = self._motion_at(th, c, tau - th.delta, ut, lag, rates)
            w_rate = np.diff(w_end, axis=1)[..., None] * hinv
            f_rate = np.diff(f_end, axis=1)[..., None] * hinv
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
                a_dot = self._lagged("motion_accel_rate", ut, lag)
                a_mean = step_mean(pc(a_dot), pc.hs, h)[..., None]
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

    def motion_samples(self) -> tuple[Array, Array]:
        """The session's gyro and accelerometer samples smoothed to the motion's signal
        (:func:`~mocap_calib.core.position.motion.motion_signals`, band-limited below the
        Nyquist frequency of the windows' samples), computed once."""
        with self._motion_lock:
            if self._motion is None:
                s = self.s
                rate = min(s.imu_rate, self.win.rate) if self.win.count else s.imu_rate
                self._motion = motion_signals(s.u, s.gyro, s.accel, 0.5 * rate)
            return self._motion

    def _lagged(self, what: str, ut: Array, lag: float) -> Array:
        """The session's accelerometer series ``what`` resampled at ``ut + lag`` (``accel``:
        the samples; ``motion_accel``: the motion's signal; ``motion_accel_rate``: its time
        derivative), once per evaluation: every chunk of windows reads the same series. The
        key holds the lag and the ends of ``ut`` (an affine map of the stamps: its ends fix
        it)."""
        key = (what, float(lag), float(ut[0]), float(ut[-1]))
        with self._motion_lock:
            hit = self._lag_cache.get(key)
        if hit is not None:
            return hit
        interp = hermite(ut, ut + lag)
        if what == "accel":
            out = interp(self.s.accel)
        elif what == "motion_accel":
            out = interp(self.motion_samples()[1])
        else:
            out = interp.derivative(self.motion_samples()[1])
        out.flags.writeable = False
        with self._motion_lock:
            if len(self._lag_cache) >= 6:  # the last evaluation's few series
                self._lag_cache.clear()
            self._lag_cache[key] = out
        return out

    def _motion_at(self, th: Theta, c: NDArray[np.int64], x: Array, ut: Array, lag: float,
                   rates: bool) -> tuple[Array, Array]:
        """The motion's corrected rate and specific force (the accelerometer resampled at the
        gyro's stamps with its lag) at IMU-clock times ``x`` (W, m+1) of windows ``c``."""
        gyro, accel = self.motion_samples()
        if self.model.has_kind("accel_lag"):
            accel = self._lagged("motion_accel", ut, lag)
        intr = Intrinsics(th.knots[c, None, 0:3], th.knots[c, None, 3:6], th.effects, th.t_mid)
        cm = correct(self.model, intr, *signals_at(gyro, accel, hermite(ut, x), x, rates),
                     sensitivities=False)
        return cm.w, cm.f

    def _gravity_inputs(self, th: Theta) -> tuple[list[int], Array]:
        """Columns of the gravity parameters and their directions: a step of length ``h`` adds
        ``h^2/2`` of them to the position and ``h`` to the velocity."""
        L = self.layout
        gcols = list(range(L.slice("gravity").start, L.slice("gravity").stop))
        dg = th.g_mag * th.g_basis  # (3, 2)
        if L.has(GRAVITY_MAGNITUDE.name):
            gcols.append(L.slice(GRAVITY_MAGNITUDE.name).start)
            dg = np.concatenate([dg, th.g_dir[:, None]], axis=1)
        return gcols, dg

    def _score_blocks(self, m: int) -> NDArray[np.int64]:
        """Block index of every sample of a window: blocks of about ``SCORE_BLOCK_S``."""
        rate = 1.0 / float(np.median(np.diff(self.win.tau[0][self.win.mask[0]])))
        per = max(1, int(round(SCORE_BLOCK_S * rate)))
        return np.arange(m + 1) // per

    def _buffer(self, name: str, shape: tuple[int, ...]) -> Array:
        """A reusable array: elements the caller never writes keep their first value, zero.
        Chunks of fewer windows get a leading slice, so that alternating chunk sizes do not
        allocate a new array at every call."""
        buffers = self._local.__dict__.setdefault("buffers", {})
        buf = buffers.get(name)
        if buf is None or buf.shape[1:] != shape[1:] or buf.shape[0] < shape[0]:
            buf = np.zeros(shape)
            buffers[name] = buf
        return buf[:shape[0]]

    # ------------------------------------------------------------------ noise and weights
    def mocap_noise_scale(self, out: EvalOut, skip: int = 5) -> tuple[float, float]:
        """Robust estimate of how much larger (variance) the mocap attitude / position noise is
        than modelled: median whitened innovation over the median of chi^2_3.

        Uses every sample past each window's first ``skip`` (where the diffuse start state
        still absorbs the innovations)."""
        use = self._level_samples(skip)
        if use.sum() < 50:
            return 1.0, 1.0
        med = float(chi2_median(3))
        return (float(np.median(out.q_rot[use])) / med, float(np.median(out.q_pos[use])) / med)

    def _level_samples(self, skip: int) -> NDArray[np.bool_]:
        """Samples for the noise level: all valid ones, outliers included. The median is
        already robust to them; keeping only the Huber inliers truncates the distribution, so
        each settling round would shrink the level further (on BROAD 21 it collapsed to 1/30
        of the innovation RMS)."""
        use = self.win.mask.copy()
        use[:, :skip] = False
        return use

    def mocap_noise_scale_axes(self, out: EvalOut, skip: int = 5) -> Array:
        """Per axis, how much larger (variance) the mocap noise is than modelled: the median of
        each whitened innovation component squared over the median of chi^2_1, on the samples
        :meth:`mocap_noise_scale` uses. Order: attitude x, y, z (IMU frame), position x, y, z
        (world frame), as :attr:`mocap_axis_scale`; each component is conditioned on the ones
        before it (the innovation covariance's Cholesky order)."""
        use = self._level_samples(skip)
        if use.sum() < 50 or out.e_white is None:
            return np.ones(6)
        med = float(chi2_median(1))
        return np.median(out.e_white[use] ** 2, axis=0) / med

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



