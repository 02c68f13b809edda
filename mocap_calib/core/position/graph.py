"""The position stage's factor graph: its variables (keys), start values, window factors,
bias random walk, weak range priors and user priors."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.graph import BatchFactors, BatchOutput
from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.model.ranges import RANGE_SIGMA
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.covariance import key_knot  # noqa: F401  (re-exported)
from mocap_calib.core.position.engine import PositionProblem, Theta, Windows, compress
from mocap_calib.core.prepare.session import PreparedSession

Array = NDArray[np.float64]

KEY_R = gtsam.symbol("r", 0)
KEY_P = gtsam.symbol("p", 0)
KEY_G = gtsam.symbol("g", 0)
KEY_T = gtsam.symbol("t", 0)
KEY_GM = gtsam.symbol("m", 0)


def key_effect(i: int) -> int:
    return gtsam.symbol("e", i)






@dataclass
class Prior:
    """A prior on one parameter block from an earlier calibration.

    Attributes:
        block: ``rotation``, ``translation``, ``gravity``, ``time_offset``, ``gyro_bias``,
            ``accel_bias`` or an effect name.
        value: the block's value in its natural form (rotation as 3x3, gravity as unit vector,
            time offset as the IMU/mocap ``t_d``, effects as their parameter vector).
        sigma: 1-sigma per tangent component.
    """

    block: str
    value: Any
    sigma: Array


@dataclass
class PositionInit:
    """Starting point of stage 3 (from stages 1-2 or from priors)."""

    R_MI: Array
    p_MI: Array
    g_dir: Array
    g_mag: float
    delta: float
    gyro_bias: Array
    accel_bias: Array
    effects: dict[str, Array] = field(default_factory=dict)
    knots: Array | None = None  # (W, 6) bias knots to start from (a previous fit's)


def theta_of(values: gtsam.Values, model: Model, W: int, fixed: PositionInit,
             t_mid: float) -> Theta:
    u3 = values.atUnit3(KEY_G)
    effects = {}
    for i, eff in enumerate(model.units):
        if eff.in_effects:
            effects[eff.name] = np.asarray(values.atVector(key_effect(i)), dtype=float)
    knots = np.stack([np.asarray(values.atVector(key_knot(w))) for w in range(W)])
    return Theta(
        R_MI=values.atRot3(KEY_R).matrix(),
        p_MI=np.asarray(values.atPoint3(KEY_P), dtype=float),
        g_dir=u3.point3(),
        g_basis=u3.basis(),
        g_mag=float(values.atVector(KEY_GM)[0]) if model.has("gravity_magnitude") else fixed.g_mag,
        delta=float(values.atVector(KEY_T)[0]) if model.has("time_offset") else fixed.delta,
        effects=effects,
        knots=knots,
        t_mid=t_mid,
    )


def _block_keys(model: Model) -> dict[str, int]:
    keys = {"rotation": KEY_R, "translation": KEY_P, "gravity": KEY_G}
    if model.has("time_offset"):
        keys["time_offset"] = KEY_T
    if model.has("gravity_magnitude"):
        keys["gravity_magnitude"] = KEY_GM
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
    """The stage-3 factor graph, its start values and the machinery behind its factors."""

    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    batch: BatchFactors
    problem: PositionProblem
    model: Model
    init: PositionInit
    block_keys: dict[str, int]
    t_mid: float
    evals: list[Any]

    def theta(self, values: gtsam.Values) -> Theta:
        return theta_of(values, self.model, self.problem.win.count, self.init, self.t_mid)


def build_position_graph(s: PreparedSession, model: Model, noise: NoiseModel, windows: Windows,
                         init: PositionInit, priors: list[Prior] | None = None) -> PositionGraph:
    """Variables, window factors, bias random-walk factors, range priors and user priors."""
    W = windows.count
    t_mid = 0.5 * (s.u[0] + s.u[-1])
    pp = PositionProblem(s, model, noise, windows)
    layout = pp.layout
    block_keys = _block_keys(model)
    key_kinds = {KEY_R: "rot3", KEY_P: "point3", KEY_G: "unit3", KEY_T: "vector",
                 KEY_GM: "vector"}
    for k in block_keys.values():
        key_kinds.setdefault(k, "vector")
    shared = list(block_keys.values())
    for w in range(W):
        key_kinds[key_knot(w)] = "vector"
    factor_keys = [shared + [key_knot(w)] for w in range(W)]
    col_keys = [(block_keys[n] if n != "knot" else None, layout.slice(n)) for n, _ in layout.blocks]

    evals: list[Any] = []  # every evaluation's output, latest last

    def evaluate(values: gtsam.Values) -> BatchOutput:
        out = pp.evaluate(theta_of(values, model, W, init, t_mid))
        evals.append(out)
        del evals[:-2]
        e, H = compress(out.gram)
        jac = [[H[w][:, sl] for _, sl in col_keys] for w in range(W)]
        return BatchOutput(list(e), jac)

    batch = BatchFactors(evaluate, factor_keys, key_kinds, shared,
                         gtsam.noiseModel.Unit.Create(layout.dim + 1))
    graph = gtsam.NonlinearFactorGraph()
    for f in batch.factors():
        graph.add(f)
    # Bias random walk between consecutive knots.
    for w in range(W - 1):
        dt = float(windows.start[w + 1] - windows.start[w])
        sig = np.r_[np.full(3, noise.gyroscope_random_walk),
                    np.full(3, noise.accelerometer_random_walk)]
        graph.add(gtsam.BetweenFactorVector(key_knot(w), key_knot(w + 1), np.zeros(6),
                                            gtsam.noiseModel.Diagonal.Sigmas(sig * np.sqrt(dt))))

    values = _start_values(model, init, W)
    _add_range_priors(graph, model, init)
    _add_user_priors(graph, priors or [], block_keys, W, s.clock_shift)
    return PositionGraph(graph, values, batch, pp, model, init, block_keys, t_mid, evals)


def _start_values(model: Model, init: PositionInit, W: int) -> gtsam.Values:
    values = gtsam.Values()
    values.insert(KEY_R, gtsam.Rot3(init.R_MI))
    values.insert(KEY_P, gtsam.Point3(*init.p_MI))
    values.insert(KEY_G, gtsam.Unit3(init.g_dir))
    if model.has("time_offset"):
        values.insert(KEY_T, np.array([init.delta]))
    if model.has("gravity_magnitude"):
        values.insert(KEY_GM, np.array([init.g_mag]))
    for i, eff in enumerate(model.units):
        if eff.in_effects:
            values.insert(key_effect(i), init.effects.get(eff.name, eff.zero()))
    for w in range(W):
        values.insert(key_knot(w), np.r_[init.gyro_bias, init.accel_bias] if init.knots is None
                      else np.asarray(init.knots[w], dtype=float))
    return values


def _add_range_priors(graph: gtsam.NonlinearFactorGraph, model: Model,
                      init: PositionInit) -> None:
    """Weak range priors (see RANGE_SIGMA) around the starting point."""
    range_priors = {
        "rotation": (KEY_R, init.R_MI),
        "translation": (KEY_P, init.p_MI),
        "gravity": (KEY_G, init.g_dir),
    }
    if model.has("time_offset"):
        range_priors["time_offset"] = (KEY_T, init.delta)
    if model.has("gravity_magnitude"):
        range_priors["gravity_magnitude"] = (KEY_GM, init.g_mag)
    for i, eff in enumerate(model.units):
        if eff.in_effects:
            range_priors[eff.name] = (key_effect(i), init.effects.get(eff.name, eff.zero()))
    for block, (key, val) in range_priors.items():
        dim = {"rotation": 3, "translation": 3, "gravity": 2}.get(block)
        if dim is None:
            dim = 1 if block in ("time_offset", "gravity_magnitude") else EFFECTS[block].dim
        graph.add(_prior_factor(block, key, val, np.full(dim, RANGE_SIGMA[block])))
    graph.add(_prior_factor("knot", key_knot(0), np.r_[init.gyro_bias, init.accel_bias],
                            np.r_[np.full(3, RANGE_SIGMA["gyro_bias"]),
                                  np.full(3, RANGE_SIGMA["accel_bias"])]))


def _add_user_priors(graph: gtsam.NonlinearFactorGraph, priors: list[Prior],
                     block_keys: dict[str, int], W: int, clock_shift: float) -> None:
    """Priors from earlier calibrations."""
    for pr in priors:
        key = block_keys.get(pr.block)
        if pr.block in ("gyro_bias", "accel_bias"):
            # A prior on the session-mean bias acts on the middle knot (random walk between).
            kw = key_knot(W // 2)
            lo = 0 if pr.block == "gyro_bias" else 3
            sig = np.full(6, 1e6)
            sig[lo:lo + 3] = pr.sigma
            val = np.zeros(6)
            val[lo:lo + 3] = pr.value
            graph.add(gtsam.PriorFactorVector(kw, val, gtsam.noiseModel.Diagonal.Sigmas(sig)))
            continue
        if key is None:
            continue  # a prior on a parameter this model does not have
        value = pr.value
        if pr.block == "time_offset":
            value = np.atleast_1d(np.asarray(value, dtype=float)) + clock_shift  # t_d -> delta
        graph.add(_prior_factor(pr.block, key, value, pr.sigma))
