"""Between the position stage's rounds: the mocap noise levels and the robust weights follow
the innovations (:mod:`mocap_calib.core.position.stage` runs the rounds; the identification of
every level from the windows' likelihood is :mod:`.noise`)."""

from __future__ import annotations

from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.graph import RELATIVE_TOL, huber_weight
from mocap_calib.core.position.engine import ROBUST_C
from mocap_calib.core.position.graph import PositionGraph

Array = NDArray[np.float64]

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


def evaluate_at(pg: PositionGraph, values: gtsam.Values) -> list[Any]:
    """A full (unfrozen) evaluation at ``values``: whitening, statistics, scores there."""
    pg.for_each("freeze_whitening", False)
    pg.batch.invalidate()
    pg.batch.output(values, 0)
    return pg.evals[-1]


def innovations_near(pg: PositionGraph, sol: gtsam.Values, cost: float) -> list[Any]:
    """The evaluation, under the round's whitening, that the levels and weights follow between
    rounds: LM's last one when its cost is within LM's convergence tolerance of the
    solution's ``cost`` (it is the solution, or the trial step LM ended on as no change: on
    long sessions one evaluation, 1.1 s at 60 min), else one at the solution."""
    at = pg.batch.evaluated_at
    if at is None or abs(pg.graph.error(at) - cost) > RELATIVE_TOL * abs(cost):
        pg.batch.output(sol, 0)
    return pg.evals[-1]
