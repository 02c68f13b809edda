"""The position stage's factor graph: its variables (keys), start values, window factors,
bias random walk, weak range priors and user priors.

A calibration may hold several takes of one rig (separate recordings, a power cycle between
them): ``R_MI``, ``p_MI``, the mocap world's gravity direction, ``|g|`` and the IMU effects are
shared; each take has its own clock offset and its own chain of bias knots (a random walk
within the take, none between takes).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.gtsam_tools import BatchFactors, BatchOutput
from mocap_calib.core.model.effects import CLOCK_OFFSET, EFFECTS, GRAVITY_MAGNITUDE, Model
from mocap_calib.core.model.parameters import RANGE_SIGMA
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.engine import EvalOut, PositionProblem, Theta, Windows, compress
from mocap_calib.core.position.session_mean import SessionMean, end_covariance, session_mean
from mocap_calib.core.prepare.session import PreparedSession

Array = NDArray[np.float64]

KEY_R = gtsam.symbol("r", 0)
KEY_P = gtsam.symbol("p", 0)
KEY_G = gtsam.symbol("g", 0)
KEY_GM = gtsam.symbol("m", 0)


def key_time(take: int) -> int:
    """GTSAM key of take ``take``'s clock offset (``delta``)."""
    return gtsam.symbol("t", take)


#: The first take's clock offset (the only one of a single-take calibration).
KEY_T = key_time(0)


def key_effect(i: int) -> int:
    return gtsam.symbol("e", i)


def key_knot(w: int) -> int:
    """GTSAM key of window ``w``'s bias knot (gyro + accel, Vector6), counted over all takes."""
    return gtsam.symbol("b", w)


@dataclass
class Prior:
    """A prior on one parameter block from an earlier calibration.

    Attributes:
        block: ``rotation``, ``translation``, ``gravity``, ``time_offset``, ``gyro_bias``,
            ``accel_bias`` or an effect name.
        value: the block's value in its natural form (rotation as 3x3, gravity as unit vector,
            time offset as the IMU/mocap ``t_d``, effects as their parameter vector).
        sigma: 1-sigma per tangent component.
        sources: the result files it comes from (two or more: their trend), as given.
    """

    block: str
    value: Any
    sigma: Array
    sources: tuple[str, ...] = ()


@dataclass(frozen=True)
class Take:
    """One recording in the position stage: its prepared session and its windows."""

    s: PreparedSession
    windows: Windows

    @property
    def t_mid(self) -> float:
        return 0.5 * float(self.s.u[0] + self.s.u[-1])


@dataclass
class TakeStart:
    """Where a take's own parameters start: its clock offset ``delta`` (mocap minus IMU
    time), its biases, and optionally the bias knots of an earlier fit."""

    delta: float
    gyro_bias: Array
    accel_bias: Array
    knots: Array | None = None


@dataclass
class PositionInit:
    """Starting point of stage 3 (from stages 1-2, or an earlier fit): the shared parameters
    and every take's own."""

    R_MI: Array
    p_MI: Array
    g_dir: Array
    g_mag: float
    takes: list[TakeStart]
    effects: dict[str, Array] = field(default_factory=dict)


def _theta(values: gtsam.Values, model: Model, take: int, knot0: int, W: int,
           init: PositionInit, t_mid: float) -> Theta:
    u3 = values.atUnit3(KEY_G)
    effects = {}
    for i, eff in enumerate(model.units):
        if eff.in_effects:
            effects[eff.name] = np.asarray(values.atVector(key_effect(i)), dtype=float)
    knots = np.stack([np.asarray(values.atVector(key_knot(knot0 + w))) for w in range(W)])
    return Theta(
        R_MI=values.atRot3(KEY_R).matrix(),
        p_MI=np.asarray(values.atPoint3(KEY_P), dtype=float),
        g_dir=u3.point3(),
        g_basis=u3.basis(),
        g_mag=(float(values.atVector(KEY_GM)[0]) if model.has_kind("gravity")
               else init.g_mag),
        delta=(float(values.atVector(key_time(take))[0]) if model.timed
               else init.takes[take].delta),
        effects=effects,
        knots=knots,
        t_mid=t_mid,
    )


def _shared_keys(model: Model) -> dict[str, int]:
    """Block name -> key of the parameters every take shares."""
    keys = {"rotation": KEY_R, "translation": KEY_P, "gravity": KEY_G}
    if model.has_kind("gravity"):
        keys[GRAVITY_MAGNITUDE.name] = KEY_GM
    for i, eff in enumerate(model.units):
        if eff.in_effects:
            keys[eff.name] = key_effect(i)
    return keys


def _prior_factor(block: str, key: int, value: Any, sigma: Array) -> gtsam.NonlinearFactor:
    nm = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigma, dtype=float))
    if block == "rotation":
        return gtsam.PriorFactorRot3(key, gtsam.Rot3(np.asarray(value)), nm)
    if block == "translation":
        return gtsam.PriorFactorPoint3(key, np.asarray(value, dtype=float), nm)
    if block == "gravity":
        return gtsam.PriorFactorUnit3(key, gtsam.Unit3(np.asarray(value, dtype=float)), nm)
    return gtsam.PriorFactorVector(key, np.atleast_1d(np.asarray(value, dtype=float)), nm)


@dataclass
class PositionGraph:
    """The stage-3 factor graph, its start values and the machinery behind its factors.

    Attributes:
        problems: one window engine per take.
        knot0: index of each take's first knot among all knots.
        shared_keys: block name -> key of the shared parameters.
        evals: the latest evaluations, each a list of per-take outputs.
        integrals: evaluations also carry the windows' bias integrals (the final one of a
            solve, whose covariance's session means then need no pass of their own).
    """

    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    batch: BatchFactors
    problems: list[PositionProblem]
    takes: list[Take]
    knot0: list[int]
    model: Model
    init: PositionInit
    shared_keys: dict[str, int]
    evals: list[list[Any]]
    integrals: bool = False

    @property
    def problem(self) -> PositionProblem:
        """The first take's engine (the only one of a single-take calibration)."""
        return self.problems[0]

    def theta(self, values: gtsam.Values, take: int = 0) -> Theta:
        return _theta(values, self.model, take, self.knot0[take],
                      self.takes[take].windows.count, self.init, self.takes[take].t_mid)

    def thetas(self, values: gtsam.Values) -> list[Theta]:
        return [self.theta(values, k) for k in range(len(self.takes))]

    def session_means(self, values: gtsam.Values) -> list[SessionMean]:
        """Every take's session-mean bias from one filter pass with the bias integrals at
        ``values`` (not kept as the graph's latest evaluation); the latest evaluation's when it
        was at ``values`` with them."""
        at = self.batch.evaluated_at
        latest = self.evals[-1] if self.evals and at is not None and values.equals(at, 0.0) \
            else None
        out = []
        for k, (pp, th, t) in enumerate(zip(self.problems, self.thetas(values), self.takes,
                                             strict=True)):
            o = latest[k] if latest is not None and latest[k].int_X is not None else None
            o = pp.evaluate(th, integral=True) if o is None else o
            out.append(session_mean(o, th.knots, t.windows, pp.noise))
        return out

    def block_keys(self, take: int) -> dict[str, int]:
        """Block name -> key of every parameter block a window of ``take`` depends on (the
        window's knot aside)."""
        keys = dict(self.shared_keys)
        if self.model.timed:
            keys[CLOCK_OFFSET.name] = key_time(take)
        return keys

    def set_weights(self, weights: list[Array]) -> None:
        for pp, w in zip(self.problems, weights, strict=True):
            pp.weights = np.asarray(w, dtype=float).copy()

    def for_each(self, fn_name: str, *args: Any) -> None:
        """Call a method of every take's engine (noise and whitening changes)."""
        for pp in self.problems:
            getattr(pp, fn_name)(*args)


def build_position_graph(takes: list[Take], model: Model, noise: NoiseModel,
                         init: PositionInit,
                         priors: list[Prior] | None = None) -> PositionGraph:
    """Variables, window factors (with the end rows that tie each window to the next knot), range
    priors and user priors."""
    problems = [PositionProblem(t.s, model, noise, t.windows) for t in takes]
    layout = problems[0].layout
    shared = _shared_keys(model)
    knot0 = list(np.cumsum([0, *[t.windows.count for t in takes[:-1]]]).astype(int))
    factor_keys: list[list[int]] = []
    col_keys: list[list[tuple[int | None, slice]]] = []
    for k, t in enumerate(takes):
        blocks = {**shared, **({CLOCK_OFFSET.name: key_time(k)} if model.timed else {})}
        cols = [(blocks[n] if n != "knot" else None, layout.slice(n))
                for n, _ in layout.blocks]
        for w in range(t.windows.count):
            # A factor's keys in the order of its Jacobian's column blocks (the layout's);
            # then the next knot, which the window's end bias meets (all but a take's last).
            keys = [key if key is not None else key_knot(knot0[k] + w) for key, _ in cols]
            sls = [sl for _, sl in cols]
            if w + 1 < t.windows.count:
                keys.append(key_knot(knot0[k] + w + 1))
                sls.append(slice(layout.dim, layout.dim + 6))
            factor_keys.append(keys)
            col_keys.append(sls)
    # A weak reference: the graph (C++) holds the factors' callbacks, which hold this
    # closure; a strong one would be a cycle through C++ that the collector cannot see, and
    # every refit's arrays would live until the process ends.
    pg_ref: list[weakref.ref[PositionGraph]] = []
    evals: list[list[Any]] = []  # every evaluation's per-take outputs, latest last

    def evaluate(values: gtsam.Values) -> BatchOutput:
        # Only the latest evaluation is kept (who needs an earlier one holds it): the old one
        # goes first, so that two sets of (windows x samples) outputs never coexist here.
        evals.clear()
        integral = _alive(pg_ref[0]).integrals
        outs = [pp.evaluate(th, integral=integral)
                for pp, th in zip(problems, _alive(pg_ref[0]).thetas(values), strict=True)]
        evals.append(outs)
        errs: list[Array] = []
        Hs: list[Array] = []
        for pp, th, o, t in zip(problems, _alive(pg_ref[0]).thetas(values), outs, takes,
                                strict=True):
            G = _bridged(o, th.knots, t.windows, pp.noise, layout.slice("knot"))
            for g in (G, o.gram[-1:]):
                if len(g) == 0:
                    continue
                e, H = compress(g)
                errs += list(e)
                Hs += list(H)
        jac = [[Hs[w][:, sl] for sl in col_keys[w]] for w in range(len(col_keys))]
        return BatchOutput(errs, jac)

    noises = [gtsam.noiseModel.Unit.Create(layout.dim + (7 if len(c) > len(layout.blocks) else 1))
              for c in col_keys]
    batch = BatchFactors(evaluate, factor_keys, noises)
    graph = gtsam.NonlinearFactorGraph()
    for f in batch.factors():
        graph.add(f)
    # No walk factor between consecutive knots: each window's filter lets the bias wander from
    # its knot, and its end rows (_bridged) tie the end bias to the next knot with the walk over
    # the gap, so the wander between knots counts once (docs/validation.md, bias walk study).
    values = _start_values(model, init, takes, knot0)
    _add_range_priors(graph, model, init, knot0)
    _add_user_priors(graph, priors or [], shared, model, takes, knot0)
    pg = PositionGraph(graph, values, batch, problems, takes, knot0, model, init, shared, evals)
    pg_ref.append(weakref.ref(pg))
    return pg


def _bridged(o: EvalOut, knots: Array, win: Windows, nz: NoiseModel, ks: slice) -> Array:
    """Every window's Gram matrix but the last's, extended by the next knot's 6 columns
    (before ``r``) and the rows where its end bias meets that knot: ``r_T = b_next - b``,
    ``J_T`` +I (next knot) and -I (this knot), minus the filter's end-state mean, whitened by
    the end bias covariance plus the walk over the gap to the next window."""
    assert o.term_X is not None and o.term_P is not None  # every filter pass fills them
    gram, tX = o.gram[:-1], o.term_X[:-1]
    n, p = gram.shape[0], gram.shape[-1] - 1
    G = np.zeros((n, p + 7, p + 7))
    if n == 0:
        return G
    G[:, :p, :p] = gram[:, :p, :p]
    G[:, :p, p + 6] = gram[:, :p, p]
    G[:, p + 6, :p] = gram[:, p, :p]
    G[:, p + 6, p + 6] = gram[:, p, p]
    N = np.zeros((n, 6, p + 7))
    N[:, :, ks] -= np.eye(6)
    N[:, :, p:p + 6] += np.eye(6)
    N[:, :, p + 6] = knots[1:] - knots[:-1]
    N[:, :, :p] -= tX[:, :, :p]
    N[:, :, p + 6] -= tX[:, :, p]
    L = np.linalg.cholesky(end_covariance(o.term_P, win, nz))
    Nw = np.linalg.solve(L, N)
    # The end rows' whitened scores (the sandwich's): parameters, then the next knot.
    o.extras["term_scores"] = np.einsum("nic,ni->nc", Nw[:, :, :p + 6], Nw[:, :, p + 6])
    return G + np.swapaxes(Nw, 1, 2) @ Nw


def _alive(ref: weakref.ref[PositionGraph]) -> PositionGraph:
    pg = ref()
    if pg is None:  # only GTSAM holding factors of a graph nobody keeps could get here
        raise RuntimeError("position graph evaluated after it was released")
    return pg


def _start_values(model: Model, init: PositionInit, takes: list[Take],
                  knot0: list[int]) -> gtsam.Values:
    values = gtsam.Values()
    values.insert(KEY_R, gtsam.Rot3(init.R_MI))
    values.insert(KEY_P, gtsam.Point3(*init.p_MI))
    values.insert(KEY_G, gtsam.Unit3(init.g_dir))
    if model.has_kind("gravity"):
        values.insert(KEY_GM, np.array([init.g_mag]))
    for i, eff in enumerate(model.units):
        if eff.in_effects:
            values.insert(key_effect(i), init.effects.get(eff.name, eff.zero()))
    for k, (t, st) in enumerate(zip(takes, init.takes, strict=True)):
        if model.timed:
            values.insert(key_time(k), np.array([st.delta]))
        for w in range(t.windows.count):
            values.insert(key_knot(knot0[k] + w), np.r_[st.gyro_bias, st.accel_bias]
                          if st.knots is None else np.asarray(st.knots[w], dtype=float))
    return values


def _add_range_priors(graph: gtsam.NonlinearFactorGraph, model: Model,
                      init: PositionInit, knot0: list[int]) -> None:
    """Weak range priors (see RANGE_SIGMA) around the starting point."""
    range_priors: dict[str, tuple[int, Any]] = {
        "rotation": (KEY_R, init.R_MI),
        "translation": (KEY_P, init.p_MI),
        "gravity": (KEY_G, init.g_dir),
    }
    if model.has_kind("gravity"):
        range_priors[GRAVITY_MAGNITUDE.name] = (KEY_GM, init.g_mag)
    for i, eff in enumerate(model.units):
        if eff.in_effects:
            range_priors[eff.name] = (key_effect(i), init.effects.get(eff.name, eff.zero()))
    for block, (key, val) in range_priors.items():
        dim = {"rotation": 3, "translation": 3, "gravity": 2}.get(block)
        if dim is None:
            dim = EFFECTS[block].dim
        graph.add(_prior_factor(block, key, val, np.full(dim, RANGE_SIGMA[block])))
    knot_sigma = np.r_[np.full(3, RANGE_SIGMA["gyro_bias"]), np.full(3, RANGE_SIGMA["accel_bias"])]
    for k, st in enumerate(init.takes):
        if model.timed:
            graph.add(_prior_factor(CLOCK_OFFSET.name, key_time(k), st.delta,
                                    np.full(1, CLOCK_OFFSET.range_sigma)))
        graph.add(_prior_factor("knot", key_knot(knot0[k]), np.r_[st.gyro_bias, st.accel_bias],
                                knot_sigma))


def _add_user_priors(graph: gtsam.NonlinearFactorGraph, priors: list[Prior],
                     shared: dict[str, int], model: Model, takes: list[Take],
                     knot0: list[int]) -> None:
    """Priors from earlier calibrations; those of a take's own parameters (clock offset,
    biases) act on every take."""
    for pr in priors:
        if pr.block in ("gyro_bias", "accel_bias"):
            # A prior on the session-mean bias acts on the middle knot (random walk between).
            lo = 0 if pr.block == "gyro_bias" else 3
            sig = np.full(6, 1e6)
            sig[lo:lo + 3] = pr.sigma
            val = np.zeros(6)
            val[lo:lo + 3] = pr.value
            for k, t in enumerate(takes):
                kw = key_knot(knot0[k] + t.windows.count // 2)
                graph.add(gtsam.PriorFactorVector(kw, val,
                                                  gtsam.noiseModel.Diagonal.Sigmas(sig)))
            continue
        if pr.block == CLOCK_OFFSET.name:  # a take's own variable
            if not model.timed:
                continue
            for k, t in enumerate(takes):  # t_d -> delta, on the take's own clocks
                value = np.atleast_1d(np.asarray(pr.value, dtype=float)) + t.s.clock_shift
                graph.add(_prior_factor(pr.block, key_time(k), value, pr.sigma))
            continue
        key = shared.get(pr.block)
        if key is None:
            continue  # a prior on a parameter this model does not have
        graph.add(_prior_factor(pr.block, key, pr.value, pr.sigma))
