"""Refits of a finished position stage: a subset of its windows (segments, takes) or other
noise models, each from the solution by Gauss-Newton steps, and the comparisons made on
them (largest pairwise |difference| / combined sigma)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.parameters import (
    COMPARED,
    ROTATION,
    TIME_OFFSET,
    TRANSLATION,
    Parameter,
)
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.engine import Theta
from mocap_calib.core.position.graph import PositionInit, Prior, Take, TakeStart
from mocap_calib.core.position.stage import (
    FINAL_EVALUATION,
    Keep,
    PositionResult,
    PositionSolver,
    Rounds,
    Steps,
    Weighting,
)

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

def init_from(pos: PositionResult, which: list[IntArray]) -> PositionInit:
    """The solution as a start, for the windows ``which`` of every take (empty: the take is
    left out)."""
    starts = [TakeStart(t.delta, t.knots[w][:, 0:3].mean(axis=0), t.knots[w][:, 3:6].mean(axis=0),
                        knots=t.knots[w])
              for t, w in zip(pos.takes, which, strict=True) if len(w)]
    return PositionInit(pos.R_MI, pos.p_MI, pos.g_dir, pos.g_mag, starts, dict(pos.effects))


def refit(pos: PositionResult, model: Model, which: list[IntArray], *,
          noise: NoiseModel | None = None, adapt_noise: bool = False, reweight: bool = False,
          priors: list[Prior] | None = None, max_iterations: int = 30,
          one_step: bool | int = True,
          settled: Callable[[Theta, Theta], bool] | None = None,
          time_mean: bool = False) -> PositionResult:
    """The solution refitted on the windows ``which`` of every take, with its robust weights
    (and with ``noise`` instead of its noise model): ``one_step`` Gauss-Newton steps (``True``:
    one), or with ``one_step`` false LM rounds to convergence. The biases' covariance is the
    knots' mean's own (what comparing two fits needs), with ``time_mean`` the reported kind."""
    kept = [k for k, w in enumerate(which) if len(w)]
    takes = [Take(pos.takes[k].s, pos.takes[k].windows.subset(which[k])) for k in kept]
    weighting = Weighting([pos.takes[k].weights[which[k]] for k in kept], pos.axis_scale)
    solver = PositionSolver(takes, model, noise or pos.noise, priors)
    init, keep = init_from(pos, which), Keep(series=False, time_mean=time_mean)
    if not one_step:
        return solver.solve(init, Rounds(robust=False, adapt_noise=adapt_noise,
                                         max_iterations=max_iterations), weighting, keep)
    # The first step evaluates at the solution: under its own noise model the windows'
    # outputs are the solution's (its evaluation, kept for this).
    full = pos.memo.get(FINAL_EVALUATION, lambda: []) if noise is None else []
    seeds = [replace(full[k], which=which[k]) if full else None for k in kept]
    return solver.refit(init, Steps(int(one_step), adapt_noise, reweight, settled), weighting,
                        keep, seeds)


def everything(pos: PositionResult) -> list[IntArray]:
    return [np.arange(t.windows.count) for t in pos.takes]


@dataclass(frozen=True)
class FitAnswer:
    """One refit's answer for the compared parameters (``t_d``: the first take's, relative to
    its raw stamps; None when not estimated) and their 1-sigma."""

    R_MI: Array
    p_MI: Array
    t_d: float | None
    sigma: dict[Parameter, Array]

    @classmethod
    def of(cls, fit: PositionResult, timed: bool) -> FitAnswer:
        sig = sigmas(fit)
        t_d = None
        if not timed:
            sig.pop(TIME_OFFSET, None)
        elif TIME_OFFSET in sig:
            t_d = float(fit.takes[0].delta - fit.takes[0].s.clock_shift)
        return cls(fit.R_MI, fit.p_MI, t_d, sig)


def z_pair(a: FitAnswer | Theta | PositionResult, b: FitAnswer | Theta | PositionResult,
           sa: dict[Parameter, Array], sb: dict[Parameter, Array] | None
           ) -> dict[Parameter, float]:
    """Per compared parameter, the largest per-axis |a - b| / sigma (combined when ``sb`` is
    given)."""
    def comb(p: Parameter) -> Array:
        return sa[p] if sb is None else np.hypot(sa[p], sb[p])

    out = {ROTATION: float(np.max(np.abs(ROTATION.difference(a.R_MI, b.R_MI)) / comb(ROTATION))),
           TRANSLATION: float(np.max(np.abs(a.p_MI - b.p_MI) / comb(TRANSLATION)))}
    if sa.get(TIME_OFFSET) is not None and (sb is None or sb.get(TIME_OFFSET) is not None):
        ta = a.t_d if isinstance(a, FitAnswer) else a.delta
        tb = b.t_d if isinstance(b, FitAnswer) else b.delta
        if ta is not None and tb is not None:
            out[TIME_OFFSET] = float(abs(ta - tb) / comb(TIME_OFFSET)[0])
    return out


def sigmas(pos: PositionResult) -> dict[Parameter, Array]:
    """The statistical 1-sigma of the compared parameters the fit estimated."""
    return {p: np.sqrt(np.diag(pos.cov[p.name])) for p in COMPARED if p.name in pos.cov}
