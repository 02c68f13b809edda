"""Does the answer hold up across the session? Its time segments (thirds by default), and its
takes, each calibrated on its own (from the full solution, with its noise model and robust
weights), each with its own sigmas. If the sigmas are honest, they agree within them: the
largest pairwise |difference| / combined sigma per parameter stays below about 3. User priors
are left out: a prior shared by all segments would correlate them and hide a disagreement.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core import interrupt
from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.parameters import ROTATION, TIME_OFFSET, TRANSLATION, Parameter
from mocap_calib.core.model.stats import chi2_sf
from mocap_calib.core.position.stage import PositionResult
from mocap_calib.core.uncertainty.refit import FitAnswer, refit, z_pair
from mocap_calib.errors import CalibrationError, Interrupted

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: The check fails when two segments differ by more than this many combined sigmas.
MAX_PAIR_Z = 3.0


@dataclass(frozen=True)
class SegmentEstimate:
    """One segment's answer (``t_d`` relative to the raw stamps, of a single take) with its
    1-sigma; ``start_s`` on the clock of ``take``, ``end_s`` on that of ``end_take`` (takes
    counted from 1; a segment of several takes spans from one to the other)."""

    start_s: float
    end_s: float
    est: FitAnswer
    take: int | None = None
    end_take: int | None = None


@dataclass(frozen=True)
class Consistency:
    """Segments, their largest pairwise |difference| / combined sigma per compared parameter,
    and the Birge ratio of each (``sqrt(chi2 / dof)`` of the segments about their weighted
    mean; about 1 when they scatter as their sigmas say); ``note``: why there are none (a
    segment too short, or one that could not be calibrated on its own)."""

    segments: tuple[SegmentEstimate, ...] = ()
    max_z: dict[Parameter, float] = field(default_factory=dict)
    birge: dict[Parameter, float] = field(default_factory=dict)
    note: str = ""

    def failed(self, p: Parameter) -> bool:
        """The check fails for ``p``: two segments disagree beyond MAX_PAIR_Z."""
        return self.max_z.get(p, 0.0) > MAX_PAIR_Z

    def factor(self, p: Parameter) -> float:
        """How much the full session's statistical sigma of ``p`` must grow to cover the
        segments: where the check fails, the larger of the Birge ratio and max_z / 3 (the
        segments' own sigmas grown as much then agree within 3); else 1."""
        if not self.failed(p):
            return 1.0
        return max(self.birge.get(p, 1.0), self.max_z[p] / MAX_PAIR_Z)

    def p_value(self, p: Parameter) -> float:
        r = self.birge.get(p)
        if r is None or len(self.segments) < 2:
            return 1.0
        dof = (len(self.segments) - 1) * p.dim
        return float(chi2_sf(r * r * dof, dof))


def _thirds(pos: PositionResult, k: int) -> list[list[IntArray]]:
    """The windows of every take split into ``k`` segments of about equal time, in take
    order: per segment, per take, the window indices."""
    lengths = np.concatenate([t.windows.end - t.windows.start for t in pos.takes])
    take_of = np.concatenate([np.full(t.windows.count, i) for i, t in enumerate(pos.takes)])
    index = np.concatenate([np.arange(t.windows.count) for t in pos.takes])
    mid = np.cumsum(lengths) - 0.5 * lengths
    seg_of = np.minimum((mid / lengths.sum() * k).astype(int), k - 1)
    return [[index[(seg_of == i) & (take_of == j)] for j in range(len(pos.takes))]
            for i in range(k)]


def segment_consistency(pos: PositionResult, model: Model, k: int = 3,
                        max_iterations: int = 30, one_step: bool = True) -> Consistency:
    """Calibrate ``k`` time segments of the session (over its takes in order) on their own
    and compare them (each by one Gauss-Newton step from the full solution; ``one_step``
    off: LM to convergence)."""
    if k < 2:
        return Consistency()
    return _compare(pos, model, _thirds(pos, k), max_iterations, by_take=False,
                    one_step=one_step)


def take_consistency(pos: PositionResult, model: Model,
                     max_iterations: int = 30) -> Consistency:
    """Calibrate every take on its own and compare them (several takes only)."""
    n = len(pos.takes)
    if n < 2:
        return Consistency()
    which = [[np.arange(t.windows.count) if j == i else np.zeros(0, np.int64)
              for j, t in enumerate(pos.takes)] for i in range(n)]
    return _compare(pos, model, which, max_iterations, by_take=True)


def _compare(pos: PositionResult, model: Model, parts: list[list[IntArray]],
             max_iterations: int, by_take: bool, one_step: bool = True) -> Consistency:
    segments: list[SegmentEstimate] = []
    single = len(pos.takes) == 1  # takes have clocks of their own: t_d is not compared
    what = "take" if by_take else "segment"
    for i, which in enumerate(parts):
        interrupt.check()
        if sum(len(w) for w in which) < 2:
            return Consistency(note=f"{what} {i + 1} has fewer than 2 windows: too short to "
                                    "compare")
        try:
            fit = refit(pos, model, which, max_iterations=max_iterations, one_step=one_step)
        except Interrupted:
            raise
        except (CalibrationError, np.linalg.LinAlgError, RuntimeError) as err:
            return Consistency(note=f"{what} {i + 1} could not be calibrated on its own ({err})")
        takes = [j for j, w in enumerate(which) if len(w)]
        t0 = pos.takes[takes[0]]
        w0, w1 = which[takes[0]][0], which[takes[-1]][-1]
        est = FitAnswer.of(fit, single)
        segments.append(SegmentEstimate(
            float(t0.windows.start[w0] - t0.s.tau[0]),
            float(pos.takes[takes[-1]].windows.end[w1] - pos.takes[takes[-1]].s.tau[0]),
            est, *((takes[0] + 1, takes[-1] + 1) if (by_take or len(pos.takes) > 1)
                   else (None, None))))
    max_z: dict[Parameter, float] = {}
    for a, b in itertools.combinations(segments, 2):
        for p, v in z_pair(a.est, b.est, a.est.sigma, b.est.sigma).items():
            max_z[p] = max(max_z.get(p, 0.0), v)
    return Consistency(tuple(segments), max_z, _birge(segments))


def _birge(segs: list[SegmentEstimate]) -> dict[Parameter, float]:
    """``sqrt(chi2 / dof)`` of the segments about their inverse-variance weighted mean."""
    out = {}
    R0 = segs[0].est.R_MI
    vals = {ROTATION: [ROTATION.difference(R0, s.est.R_MI) for s in segs],
            TRANSLATION: [s.est.p_MI for s in segs]}
    sig = {p: [s.est.sigma[p] for s in segs] for p in vals}
    if all(s.est.t_d is not None for s in segs):
        vals[TIME_OFFSET] = [np.array([s.est.t_d]) for s in segs]
        sig[TIME_OFFSET] = [s.est.sigma[TIME_OFFSET] for s in segs]
    for p in vals:
        x, sg = np.array(vals[p]), np.array(sig[p])
        w = 1.0 / sg**2
        mean = (w * x).sum(axis=0) / w.sum(axis=0)
        chi2 = float((w * (x - mean) ** 2).sum())
        out[p] = float(np.sqrt(chi2 / ((len(segs) - 1) * x.shape[1])))
    return out
