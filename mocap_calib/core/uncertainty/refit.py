"""Refits of a finished position stage: a subset of its windows (segments, takes) or other
noise models, each from the solution by Gauss-Newton steps, and the comparisons made on
them (largest pairwise |difference| / combined sigma)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import CLOCK_OFFSET, Model
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.engine import Theta
from mocap_calib.core.position.graph import PositionInit, Prior, Take, TakeStart
from mocap_calib.core.position.stage import PositionResult, run_position_stage

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Parameters compared between segments, takes and noise models.
COMPARED = ("R_MI", "p_MI", "t_d")


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
          one_step: bool | int = True, settled: Any = None) -> PositionResult:
    """The solution refitted on the windows ``which`` of every take, with its robust weights
    (and with ``noise`` instead of its noise model)."""
    keep = [k for k, w in enumerate(which) if len(w)]
    takes = [Take(pos.takes[k].s, pos.takes[k].windows.subset(which[k])) for k in keep]
    weights = [pos.takes[k].weights[which[k]] for k in keep]
    return run_position_stage(takes, model, noise or pos.noise, init_from(pos, which), priors,
                              robust=False, adapt_noise=adapt_noise, weights=weights,
                              max_iterations=max_iterations, one_step=one_step,
                              reweight=reweight, settled=settled, axis_scale=pos.axis_scale,
                              series=False)


def everything(pos: PositionResult) -> list[IntArray]:
    return [np.arange(t.windows.count) for t in pos.takes]


@dataclass
class Estimate:
    """One refit's answer (``t_d``: the first take's, relative to its raw stamps) and 1-sigma."""

    R_MI: Array
    p_MI: Array
    t_d: float | None
    sigma: dict[str, Array]

    @classmethod
    def of(cls, fit: PositionResult, timed: bool) -> Estimate:
        sig = {"R_MI": np.sqrt(np.diag(fit.cov["rotation"])),
               "p_MI": np.sqrt(np.diag(fit.cov["translation"]))}
        t_d = None
        if timed and CLOCK_OFFSET.name in fit.cov:
            sig["t_d"] = np.sqrt(np.diag(fit.cov[CLOCK_OFFSET.name]))
            t_d = float(fit.takes[0].delta - fit.takes[0].s.clock_shift)
        return cls(fit.R_MI, fit.p_MI, t_d, sig)


def z_pair(a: Estimate | Theta | PositionResult, b: Estimate | Theta | PositionResult,
           sa: dict[str, Array], sb: dict[str, Array] | None) -> dict[str, float]:
    """Largest per-axis |a - b| / sigma (combined when ``sb`` is given)."""
    def comb(k: str) -> Array:
        return sa[k] if sb is None else np.hypot(sa[k], sb[k])

    out = {"R_MI": float(np.max(np.abs(so3.log(a.R_MI.T @ b.R_MI)) / comb("R_MI"))),
           "p_MI": float(np.max(np.abs(a.p_MI - b.p_MI) / comb("p_MI")))}
    if sa.get("t_d") is not None and (sb is None or sb.get("t_d") is not None):
        ta = a.t_d if isinstance(a, Estimate) else a.delta
        tb = b.t_d if isinstance(b, Estimate) else b.delta
        if ta is not None and tb is not None:
            out["t_d"] = float(abs(ta - tb) / comb("t_d")[0])
    return out


def sigmas(pos: PositionResult) -> dict[str, Array]:
    d = {"R_MI": np.sqrt(np.diag(pos.cov["rotation"])),
         "p_MI": np.sqrt(np.diag(pos.cov["translation"]))}
    if CLOCK_OFFSET.name in pos.cov:
        d["t_d"] = np.sqrt(np.diag(pos.cov[CLOCK_OFFSET.name]))
    return d
