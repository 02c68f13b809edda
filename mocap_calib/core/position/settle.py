"""How the position stage's solve proceeds: rounds of LM on a fixed cost (a full solve) or
Gauss-Newton steps (a refit near a solution), and between them the mocap noise levels and the
robust weights following the innovations (:class:`mocap_calib.core.position.stage.
PositionSolver` calls them; the identification of every level from the windows' likelihood is
:mod:`.noise`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from mocap_calib.core import interrupt
from mocap_calib.core.gtsam_tools import (
    PREDICTED_TOL,
    RELATIVE_TOL,
    SolveReport,
    huber_weight,
    predicted_decrease,
    require_converged,
    run_lm,
)
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.engine import ROBUST_C, Theta
from mocap_calib.core.position.graph import PositionGraph
from mocap_calib.core.position.noise import NoiseIdentification, identify_noise

Array = NDArray[np.float64]

IterationHook = Callable[[str, int, dict[str, Any], float], None]

#: LM iterations of a round that settles the levels and weights (the last round converges).
SETTLING_ITERATIONS = 4
#: Rounds end when the cost moves by less than this fraction and the levels by < 5 %.
COST_SETTLED = 1e-3

def mocap_levels(pg: PositionGraph, outs: list[Any], skip: int = 5) -> Array:
    """Per axis (attitude x, y, z; position x, y, z), how much larger (variance) the mocap
    noise is than modelled, from every take's innovations (each take's estimate weighted by
    its samples; see :meth:`PositionProblem.mocap_noise_scale_axes`)."""
    total, weight = np.zeros(6), 0.0
    for pp, out in zip(pg.problems, outs, strict=True):
        n = float(np.sum(pp.win.mask[:, skip:]))
        total += n * pp.mocap_noise_scale_axes(out, skip)
        weight += n
    return total / max(weight, 1.0)


def huber_weights(d: Array, mask: NDArray[np.bool_], c: float = ROBUST_C) -> Array:
    """Huber's weights on the whitened innovation norms ``d``: 1 up to ``c``, ``c / d``
    beyond (convex: one fixed point)."""
    w = huber_weight(d, c)
    w[~mask] = 1.0
    return np.maximum(w, 1e-6)


def settle(pg: PositionGraph, outs: list[Any], adapt_noise: bool, robust: bool,
           noise_scale: Array) -> tuple[bool, float]:
    """Between rounds: the mocap levels and the weights follow the innovations. Returns
    (anything changed, the largest relative level change)."""
    changed, moved = False, 0.0
    d_scale = 1.0  # how the whitened innovations shrink with the noise change
    if adapt_noise:
        axes = np.clip(mocap_levels(pg, outs), 0.05, 400.0)
        moved = float(np.max(np.abs(np.log(axes))))
        if moved > np.log(1.05):
            # The two levels (geometric means) go to the noise model, the shape to the axes.
            s_rot, s_pos = (float(np.exp(np.mean(np.log(axes[i:i + 3])))) for i in (0, 3))
            shape = axes / np.repeat([s_rot, s_pos], 3)
            for pp in pg.problems:
                pp.scale_mocap_noise(s_rot, s_pos)
                pp.mocap_axis_scale = pp.mocap_axis_scale * shape
            noise_scale *= (s_rot, s_pos)
            d_scale = float(np.prod(axes) ** (-1.0 / 12.0))
            changed = True
    if robust:
        for pp, out in zip(pg.problems, outs, strict=True):
            w = huber_weights(out.d_raw * d_scale, pp.win.mask)
            if float(np.max(np.abs(w - pp.weights), initial=0.0)) > 0.05:
                changed = True
            pp.weights = w
    return changed, moved


def evaluate_at(pg: PositionGraph, values: gtsam.Values, integrals: bool = False) -> list[Any]:
    """A full (unfrozen) evaluation at ``values``: whitening, statistics, scores there (with
    ``integrals``: the bias integrals too)."""
    pg.for_each("freeze_whitening", False)
    pg.integrals = integrals
    pg.batch.invalidate()
    pg.batch.output(values, 0)
    pg.integrals = False
    return pg.evals[-1]


def converged_at(pg: PositionGraph, values: gtsam.Values, hook: History,
                 integrals: bool) -> SolveReport | None:
    """The last round's first question asked of the full (unfrozen) evaluation at
    ``values``: would a Gauss-Newton step still lower the cost by :data:`PREDICTED_TOL`? If
    not, the round is over and that evaluation is the solution's (what :func:`evaluate_at`
    would compute again); else None (the round's LM runs, frozen). A frozen whitening replays
    its record, which differs from the full one only by the record's single-precision
    increments."""
    t0 = time.perf_counter()
    evaluate_at(pg, values, integrals)
    if predicted_decrease(pg.graph, values) >= PREDICTED_TOL:
        return None
    err = float(pg.graph.error(values))
    hook(0, values, err)  # the round's start, as LM records it
    return SolveReport(0, err, err, time.perf_counter() - t0, converged=True,
                       reason="converged", last_decrease=0.0)


def innovations_near(pg: PositionGraph, sol: gtsam.Values, cost: float) -> list[Any]:
    """The evaluation, under the round's whitening, that the levels and weights follow between
    rounds: LM's last one when its cost is within LM's convergence tolerance of the
    solution's ``cost`` (it is the solution, or the trial step LM ended on as no change: on
    long sessions one evaluation, 1.1 s at 60 min), else one at the solution."""
    at = pg.batch.evaluated_at
    if at is None or abs(pg.graph.error(at) - cost) > RELATIVE_TOL * abs(cost):
        pg.batch.output(sol, 0)
    return pg.evals[-1]


class History:
    """Records every LM iterate (and the first evaluation's innovations, for the "before"
    figures: only those, not the whole evaluation, are kept for the stage)."""

    def __init__(self, pg: PositionGraph, on_iteration: IterationHook | None) -> None:
        self.pg = pg
        self.on_iteration = on_iteration
        self.records: list[dict[str, Any]] = []
        self.first_innovations: list[Array] | None = None

    def __call__(self, it: int, v: gtsam.Values, err: float) -> None:
        th = self.pg.theta(v)
        rec = {"iteration": len(self.records), "cost": float(err), "R_MI": th.R_MI.tolist(),
               "p_MI": th.p_MI.tolist(), "g_dir": th.g_dir.tolist(), "delta": th.delta,
               "gyro_bias": th.knots[:, 0:3].mean(axis=0).tolist(),
               "accel_bias": th.knots[:, 3:6].mean(axis=0).tolist()}
        self.records.append(rec)
        if self.first_innovations is None and self.pg.evals:
            self.first_innovations = [o.innovation for o in self.pg.evals[-1]]
        if self.on_iteration is not None:
            self.on_iteration("position", rec["iteration"], rec, float(err))


@dataclass
class Fit:
    """Where a solve ended and how it got there."""

    values: gtsam.Values
    iterations: int
    noise_scale: Array
    innovations0: list[Array] | None  # per take, the innovations at the start values
    rounds: int = 1
    linearized_at: gtsam.Values | None = None  # Gauss-Newton: the last linearisation point
    capped: bool = False  # the settling rounds ended at their cap, the levels still moving
    #: The noise model the data prefer (a full solve asked to identify it), else None.
    identification: NoiseIdentification | None = None


def gauss_newton_steps(pg: PositionGraph, adapt_noise: bool = False, steps: int = 1,
                       robust: bool = False,
                       settled: Callable[[Theta, Theta], bool] | None = None) -> Fit:
    """Gauss-Newton steps from the start values; between steps the mocap levels (with
    ``adapt_noise``) and the weights (with ``robust``) follow the innovations of the last
    linearisation, as between a full run's rounds. One evaluation per step; after the second,
    ``settled(before, after)`` may end the steps early. The noise model's kind (white or
    correlated) stays as given."""
    pg.for_each("freeze_whitening", False)
    noise_scale = np.ones(2)
    values = pg.values
    inn0: list[Array] | None = None
    k = 0
    at = values
    for k in range(steps):
        at = values
        lin = pg.graph.linearize(at)
        interrupt.check()  # a signal during the evaluation only set the request
        outs = pg.evals[-1]
        inn0 = [o.innovation for o in outs] if inn0 is None else inn0
        values = values.retract(lin.optimize())
        if k == steps - 1 or (k >= 1 and settled is not None
                              and settled(pg.theta(at), pg.theta(values))):
            break
        settle(pg, outs, adapt_noise, robust, noise_scale)
        del outs  # not alive while the next step evaluates
        pg.batch.invalidate()
    return Fit(values, k + 1, noise_scale, inn0, k + 1, linearized_at=at)


def solve_rounds(pg: PositionGraph, max_iterations: int, rounds: int, robust: bool,
                 adapt_noise: bool, hook: History,
                 progress: Callable[[str], None] | None, identify_noise: bool = False,
                 integrals: bool = False,
                 near_trials: int | None = None) -> Fit:
    """Rounds of LM on a fixed cost (whitening frozen); between rounds the mocap noise levels
    are re-estimated from the innovations and the robust weights updated. The first run goes
    to convergence from the start values; the settling rounds after it are short; once nothing
    changes (or the cost moves by less than :data:`COST_SETTLED`) one LM run goes to
    convergence (after settling rounds, its start is first checked on the full evaluation
    there: see :func:`converged_at`). The solution's final evaluation carries the bias
    integrals with ``integrals``; ``near_trials``: see :func:`run_lm`."""
    graph, batch = pg.graph, pg.batch
    iterations, sol = 0, pg.values
    inn0: list[Array] | None = None
    noise_scale = np.ones(2)
    prev_cost = None
    final = settled = rounds <= 1
    given = pg.problem.noise
    ident = None
    identification: NoiseIdentification | None = None
    rnd = 0
    while True:
        rnd += 1
        if progress is not None:
            n = sum(p.win.count for p in pg.problems)
            progress(f"position factors: {'final solve' if final else 'settling'} round {rnd} "
                     f"({n} windows)")
        if final and rnd > 1:
            done = converged_at(pg, sol, hook, integrals)
            if done is not None:
                rep = done
                outs = pg.evals[-1]
                break
        pg.for_each("freeze_whitening", True)
        batch.invalidate()
        # The first run converges (from stages 1-2, unit weights); later ones only settle the
        # levels and weights, until the last.
        limit = max_iterations if (final or rnd == 1) else SETTLING_ITERATIONS
        sol, rep = run_lm(graph, sol, limit, hook, predicted_tol=PREDICTED_TOL,
                          near_trials=near_trials)
        inn0 = hook.first_innovations if inn0 is None else inn0
        iterations += rep.iterations
        if final:
            outs = evaluate_at(pg, sol, integrals)
            break
        outs = innovations_near(pg, sol, float(rep.final_error))
        changed, moved = settle(pg, outs, adapt_noise and ident is None, robust, noise_scale)
        if identify_noise and identification is None:
            # Once, after the first solve: the levels the data prefer there, used from then
            # on when they contradict the given ones (a second identification at the final
            # solution changed no answer by a tenth of a sigma on simulated flights).
            identification = identify(pg, sol, given)
            if identification.contradicts:
                ident = identification
                moved_a = _noise_move(pg.problem.noise, ident.noise)
                for pp in pg.problems:
                    pp.noise = ident.noise
                changed, moved = changed or moved_a > np.log(1.05), max(moved, moved_a)
        cost = float(rep.final_error)
        small = prev_cost is not None and abs(prev_cost - cost) < COST_SETTLED * abs(cost)
        prev_cost = cost
        settled = (not changed) or (small and moved < np.log(1.05))
        final = settled or rnd >= rounds - 1
        del outs  # not alive while the next round evaluates (60 min: 37 MB)
        batch.invalidate()
    require_converged("position", rep, max_iterations)
    return Fit(sol, iterations, noise_scale, inn0, rnd, capped=not settled,
               identification=identification)


def identify(pg: PositionGraph, values: gtsam.Values,
             given: NoiseModel) -> NoiseIdentification:
    """The noise model the windows' likelihood prefers at ``values`` (every take)."""
    problems = [(pp, pg.theta(values, k)) for k, pp in enumerate(pg.problems)]
    return identify_noise(problems, pg.problem.noise, given)


def _noise_move(a: NoiseModel, b: NoiseModel) -> float:
    """The largest relative change of a level between two noise models (log of the ratio)."""
    keys = ("accelerometer_noise_density", "gyroscope_noise_density", "mocap_position_sigma",
            "mocap_rotation_sigma")
    return max(abs(float(np.log(getattr(b, k) / getattr(a, k)))) for k in keys)
