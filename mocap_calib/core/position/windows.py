"""Windows of the position stage and the values and layout of its parameters.

A window is a gap-free stretch of mocap samples (a few seconds); all windows are padded to the
same number of steps so that the engine can advance them in lock-step.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.prepare.session import PreparedSession

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Windows:
    """Padded window arrays (W windows, up to m steps each). The poses stay the session's
    (``R_source``, ``p_source``: not copied per window, 36 MB at 60 min); a chunk of windows
    gathers its own (:meth:`poses`)."""

    idx: NDArray[np.int64]  # (W, m+1) mocap sample index
    mask: NDArray[np.bool_]  # (W, m+1) real sample
    tau: Array  # (W, m+1)
    R_source: Array  # (N, 3, 3) the session's mocap rotations R_WM
    p_source: Array  # (N, 3) the session's mocap positions p_WM
    v0: Array  # (W, 3) IMU velocity guess at the window start (diffuse prior's mean)

    def poses(self, c: NDArray[np.int64] | slice | int = slice(None)) -> tuple[Array, Array]:
        """R_WM (..., m+1, 3, 3) and p_WM (..., m+1, 3) of windows ``c`` (gathered: a copy)."""
        idx = self.idx[c]
        return self.R_source[idx], self.p_source[idx]

    @property
    def count(self) -> int:
        return self.idx.shape[0]

    def decimate(self, k: int) -> Windows:
        """Every ``k``-th sample of every window (the last real sample kept)."""
        if k <= 1:
            return self
        W, m1 = self.idx.shape
        cols = np.arange(0, m1, k)
        mask = self.mask[:, cols]
        return Windows(self.idx[:, cols], mask, self.tau[:, cols], self.R_source,
                       self.p_source, self.v0)

    def subset(self, which: NDArray[np.int64]) -> Windows:
        """The windows ``which`` (indices), in that order (all of them in order: these, not
        a copy: a refit of the whole session would copy ~45 MB at 60 min)."""
        if len(which) == self.count and np.array_equal(which, np.arange(self.count)):
            return self
        return Windows(self.idx[which], self.mask[which], self.tau[which], self.R_source,
                       self.p_source, self.v0[which])

    @property
    def rate(self) -> float:
        """The samples' rate (Hz): the first window's median step."""
        return 1.0 / float(np.median(np.diff(self.tau[0][self.mask[0]])))

    @property
    def steps(self) -> int:
        return self.idx.shape[1] - 1

    @property
    def start(self) -> Array:
        return self.tau[:, 0]

    @property
    def end(self) -> Array:
        last = self.mask.sum(axis=1) - 1
        return self.tau[np.arange(self.count), last]

    @property
    def n_samples(self) -> int:
        return int(self.mask.sum())


#: How far the fine clock offset may move from the one the windows are cut at (s): windows
#: keep this clear of IMU gaps.
CLOCK_ROOM_S = 0.02


def make_windows(s: PreparedSession, delta: float, length: float, max_rate: float,
                 v_imu: Array, min_samples: int = 20, margin: float = 0.1) -> Windows:
    """Cut the mocap stream into gap-free windows of at most ``length`` seconds.

    Args:
        s: prepared session.
        delta: current mocap-minus-IMU time (windows stay ``margin`` inside the IMU span).
        length: window length (s).
        max_rate: mocap samples above this rate are decimated (consecutive mocap noise is rarely
            independent beyond ~100-200 Hz, and the cost is linear in the samples).
        v_imu: (M, 3) IMU velocity guess at every mocap sample (for window starts).
    """
    step = max(1, int(round(s.mocap_rate / max_rate)))
    sel = np.arange(0, len(s.tau), step)
    tau = s.tau[sel]
    inside = (tau - delta > s.u[0] + margin) & (tau - delta < s.u[-1] - margin)
    gap = max(s.gap, 3.0 * step / s.mocap_rate)
    # No window integrates across an IMU gap (with room for the fine clock offset to move).
    imu_clear = s.imu_clear(tau[:-1] - delta - CLOCK_ROOM_S, tau[1:] - delta + CLOCK_ROOM_S)
    breaks = np.flatnonzero((np.diff(tau) > gap) | (inside[1:] != inside[:-1])
                            | ~imu_clear) + 1
    segments = [seg for seg in np.split(np.arange(len(sel)), breaks) if inside[seg[0]]]
    windows: list[NDArray[np.int64]] = []
    for seg in segments:
        dur = tau[seg[-1]] - tau[seg[0]]
        n = max(1, int(np.ceil(dur / length)))
        for part in np.array_split(seg, n):
            if len(part) >= min_samples:
                windows.append(sel[part])
    if not windows:
        return Windows(np.zeros((0, 2), np.int64), np.zeros((0, 2), bool), np.zeros((0, 2)),
                       s.R_WM, s.p_WM, np.zeros((0, 3)))
    m1 = max(len(w) for w in windows)
    W = len(windows)
    idx = np.zeros((W, m1), np.int64)
    mask = np.zeros((W, m1), bool)
    for i, w in enumerate(windows):
        idx[i, : len(w)] = w
        idx[i, len(w):] = w[-1]
        mask[i, : len(w)] = True
    return Windows(idx, mask, s.tau[idx], s.R_WM, s.p_WM, v_imu[idx[:, 0]])


@dataclass
class Theta:
    """Current values of the position stage's parameters."""

    R_MI: Array
    p_MI: Array
    g_dir: Array
    g_basis: Array  # (3, 2) tangent basis of the gravity direction (GTSAM Unit3's)
    g_mag: float
    delta: float
    effects: dict[str, Array]
    knots: Array  # (W, 6): gyro bias, accel bias at each window start
    t_mid: float = 0.0


@dataclass(frozen=True)
class Layout:
    """Column layout of a window's Jacobian: global blocks, then the window's bias knot."""

    blocks: tuple[tuple[str, int], ...]

    @property
    def dim(self) -> int:
        return sum(d for _, d in self.blocks)

    def slice(self, name: str) -> slice:
        o = 0
        for n, d in self.blocks:
            if n == name:
                return slice(o, o + d)
            o += d
        raise KeyError(name)

    def has(self, name: str) -> bool:
        return any(n == name for n, _ in self.blocks)


def layout_for(model: Model) -> Layout:
    blocks: list[tuple[str, int]] = [("rotation", 3), ("translation", 3), ("gravity", 2)]
    blocks += [(eff.name, eff.dim) for eff in model.world_units()]
    blocks += [(eff.name, eff.dim) for eff in model.units if eff.in_effects]
    blocks.append(("knot", 6))
    return Layout(tuple(blocks))


@dataclass
class EvalOut:
    """One evaluation of all windows.

    Attributes:
        gram: (W, p+1, p+1) Gram matrix of the whitened ``[J | r]`` per window (r last).
        innovation: (W, m+1, 6) one-step prediction errors (rad, m) at each sample.
        d_raw: (W, m+1) whitened innovation norm with unit robust weights.
        chi2: (W,) whitened cost per window (with the robust weights used).
        logdet: (W,) sum of log det of the innovation covariances (the likelihood's other part).
        e_white: (W, m+1, 6) whitened innovations (zero at padding): each component's typical
            size tells whether the mocap noise of that axis is as modelled (the first three are
            the attitude axes in the IMU frame, the last three the position axes in the world
            frame, each conditioned on the ones before).
        scores: (W, B, p) per window and block of consecutive samples, the whitened score
            ``sum J_w^T r_w`` (only when the problem collects them, for the sandwich
            covariance).
        raw_r, raw_J: pre-whitening residuals/Jacobians (only when ``store``).
        whitened: (W, m+1, 6, p+1) whitened ``[J | r]`` rows (only when ``store``).
        extras: the filter's state-space model (only when ``store``).
    """

    gram: Array
    innovation: Array
    d_raw: Array
    chi2: Array
    logdet: Array
    e_white: Array
    scores: Array | None = None
    raw_r: Array | None = None
    raw_J: Array | None = None
    whitened: Array | None = None
    extras: dict[str, Array] = field(default_factory=dict)
    term_X: Array | None = None  # (W, 6, p+1) bias states' mean per column at the end
    term_P: Array | None = None  # (W, 6, 6) their covariance
    #: (W, 6, p+1) the window's time integral of the bias error (s), mean per column, and
    #: (W, 6, 12) its covariance and its covariance with the end bias (only when asked for)
    int_X: Array | None = None
    int_P: Array | None = None

    @property
    def q_rot(self) -> Array:
        """(W, m+1) squared whitened attitude innovation (3 dof): its typical size tells
        whether the mocap attitude noise is as modelled."""
        return np.einsum("wki,wki->wk", self.e_white[..., 0:3], self.e_white[..., 0:3])

    @property
    def q_pos(self) -> Array:
        """(W, m+1) squared whitened position innovation (3 dof)."""
        return np.einsum("wki,wki->wk", self.e_white[..., 3:6], self.e_white[..., 3:6])


@dataclass(frozen=True)
class Seed:
    """An evaluation a problem on more windows made at ``th`` (these windows are ``which``
    among its own), with the noise model, robust weights (its windows') and mocap axis scale
    it ran under. The windows' filters are independent of each other, so a problem on the
    windows ``which`` evaluating at the same parameters under the same noise and weights
    (a refit of a segment or a take from the solution) takes its windows' outputs instead of
    running the filter again (and its later evaluations use the same motion signals)."""

    th: Theta
    out: EvalOut
    which: NDArray[np.int64]
    noise: NoiseModel
    weights: Array
    axis_scale: Array
    #: The session's motion signals the evaluation used (see ``PositionProblem.use_seed``).
    motion: tuple[Array, Array] | None = None

    def reuse(self, th: Theta, noise: NoiseModel, weights: Array, axis_scale: Array,
              n_blocks: int | None) -> EvalOut | None:
        """The windows' outputs when everything they depend on is as it was (exactly; the
        gravity direction to rounding: a refit's start renormalises the unit vector), else
        None."""
        a, w = self.th, self.which
        scores = self.out.scores
        same = (noise == self.noise and th.g_mag == a.g_mag and th.delta == a.delta
                and th.t_mid == a.t_mid and th.effects.keys() == a.effects.keys()
                and (scores is None) == (n_blocks is None)
                and (scores is None or scores.shape[1] == n_blocks)
                and np.allclose(th.g_dir, a.g_dir, rtol=0.0, atol=1e-15)
                and np.allclose(th.g_basis, a.g_basis, rtol=0.0, atol=1e-15)
                and all(np.array_equal(x, y) for x, y in (
                    (th.R_MI, a.R_MI), (th.p_MI, a.p_MI), (th.knots, a.knots[w]),
                    (weights, self.weights[w]), (axis_scale, self.axis_scale),
                    *((th.effects[k], a.effects[k]) for k in th.effects))))
        if not same:
            return None
        o = self.out

        def pick(x: Array | None) -> Array | None:
            return None if x is None else x[w]
        return EvalOut(o.gram[w], o.innovation[w], o.d_raw[w], o.chi2[w], o.logdet[w],
                       o.e_white[w], pick(o.scores), term_X=pick(o.term_X),
                       term_P=pick(o.term_P))
