"""Does the answer hold up? The session in independent segments, and the answer under other
noise densities.

- Consistency: the session's windows are split by time into ``k`` segments, each calibrated on
  its own (from the full solution, with its noise model and robust weights), each with its own
  sigmas. If the sigmas are honest, the segments agree within them: the largest pairwise
  |difference| / combined sigma per parameter stays below about 3. User priors are left out
  there: a prior shared by all segments would correlate them and hide a disagreement.
- Sensitivity: the IMU noise densities (white and random walk) scaled by 3 and by 1/3 reweight
  the data; an answer that moves by more than its sigma depends on an assumption the session
  cannot check.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy import stats as sps

from mocap_calib.core import interrupt
from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import Model
from mocap_calib.core.position.graph import Prior
from mocap_calib.core.position.stage import PositionInit, PositionResult, run_position_stage
from mocap_calib.core.position.windows import Theta
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.errors import CalibrationError, Interrupted

Array = NDArray[np.float64]

#: Parameters compared between segments and under other noise densities.
COMPARED = ("R_MI", "p_MI", "t_d")


@dataclass
class SegmentEstimate:
    """One segment's answer (``t_d`` relative to the raw stamps) with its 1-sigma."""

    start_s: float
    end_s: float
    R_MI: Array
    p_MI: Array
    t_d: float | None
    sigma_R: Array
    sigma_p: Array
    sigma_t_d: float | None

    def to_dict(self) -> dict[str, Any]:
        return {"start_s": round(self.start_s, 3), "end_s": round(self.end_s, 3),
                "rotation_wxyz": so3.rotmat_to_quat(self.R_MI).tolist(),
                "translation": self.p_MI.tolist(), "time_offset": self.t_d,
                "sigma": {"rotation": self.sigma_R.tolist(), "translation": self.sigma_p.tolist(),
                          "time_offset": self.sigma_t_d}}


@dataclass
class Consistency:
    """Segments, their largest pairwise |difference| / combined sigma per parameter, and the
    Birge ratio of each parameter (``sqrt(chi2 / dof)`` of the segments about their weighted
    mean; about 1 when they scatter as their sigmas say)."""

    segments: list[SegmentEstimate] = field(default_factory=list)
    max_z: dict[str, float] = field(default_factory=dict)
    birge: dict[str, float] = field(default_factory=dict)
    note: str = ""

    def inflation(self, param: str) -> float:
        """Factor for the full session's sigma of ``param``: the Birge ratio where the segments
        disagree significantly (chi2 beyond its 95 % point), else 1."""
        r = self.birge.get(param)
        if r is None or not self.segments:
            return 1.0
        dof = (len(self.segments) - 1) * {"R_MI": 3, "p_MI": 3, "t_d": 1}[param]
        return r if r * r * dof > sps.chi2.ppf(0.95, dof) else 1.0

    def to_dict(self) -> dict[str, Any]:
        return {"segments": [s.to_dict() for s in self.segments],
                "max_pairwise_z": {k: round(v, 3) for k, v in self.max_z.items()},
                "birge_ratio": {k: round(v, 3) for k, v in self.birge.items()},
                "sigma_inflation": {k: round(self.inflation(k), 3) for k in self.birge},
                **({"note": self.note} if self.note else {})}


def _z(a: SegmentEstimate | PositionResult | Theta, b: SegmentEstimate | PositionResult | Theta,
       sa: dict[str, Array], sb: dict[str, Array] | None) -> dict[str, float]:
    """Largest per-axis |a - b| / sigma (combined when ``sb`` is given)."""
    def comb(k: str) -> Array:
        return sa[k] if sb is None else np.hypot(sa[k], sb[k])

    out = {"R_MI": float(np.max(np.abs(so3.log(a.R_MI.T @ b.R_MI)) / comb("R_MI"))),
           "p_MI": float(np.max(np.abs(a.p_MI - b.p_MI) / comb("p_MI")))}
    if sa.get("t_d") is not None and (sb is None or sb.get("t_d") is not None):
        ta = a.t_d if isinstance(a, SegmentEstimate) else a.delta
        tb = b.t_d if isinstance(b, SegmentEstimate) else b.delta
        out["t_d"] = float(abs(ta - tb) / comb("t_d")[0])
    return out


def _sigmas(pos: PositionResult) -> dict[str, Array]:
    d = {"R_MI": np.sqrt(np.diag(pos.cov["rotation"])),
         "p_MI": np.sqrt(np.diag(pos.cov["translation"]))}
    if "time_offset" in pos.cov:
        d["t_d"] = np.sqrt(np.diag(pos.cov["time_offset"]))
    return d


def _init(pos: PositionResult, which: NDArray[np.int64]) -> PositionInit:
    knots = pos.knots[which]
    return PositionInit(pos.R_MI, pos.p_MI, pos.g_dir, pos.g_mag, pos.delta,
                        knots[:, 0:3].mean(axis=0), knots[:, 3:6].mean(axis=0),
                        dict(pos.effects), knots=knots)


def segment_consistency(s: PreparedSession, model: Model, pos: PositionResult, k: int = 3,
                        max_iterations: int = 30, one_step: bool = True) -> Consistency:
    """Calibrate ``k`` time segments of the session on their own and compare them (each by
    one Gauss-Newton step from the full solution unless ``one_step`` is off)."""
    win = pos.windows
    if k < 2:
        return Consistency()
    bounds = np.linspace(win.start[0], win.end[-1], k + 1)
    seg_of = np.clip(np.searchsorted(bounds, win.start, side="right") - 1, 0, k - 1)
    out = Consistency()
    for i in range(k):
        interrupt.check()
        which = np.flatnonzero(seg_of == i)
        if len(which) < 2:
            out.note = f"segment {i + 1} has fewer than 2 windows: too short to compare"
            return Consistency(note=out.note)
        try:
            seg = run_position_stage(s, model, pos.noise, win.subset(which), _init(pos, which),
                                     robust=False, adapt_noise=False,
                                     weights=pos.weights[which], max_iterations=max_iterations,
                                     one_step=one_step)
        except Interrupted:
            raise
        except (CalibrationError, np.linalg.LinAlgError, RuntimeError) as err:
            return Consistency(note=f"segment {i + 1} could not be calibrated on its own ({err})")
        sg = _sigmas(seg)
        has_td = "t_d" in sg
        out.segments.append(SegmentEstimate(
            float(bounds[i] - s.tau[0]), float(bounds[i + 1] - s.tau[0]), seg.R_MI, seg.p_MI,
            float(seg.delta - s.clock_shift) if has_td else None, sg["R_MI"], sg["p_MI"],
            float(sg["t_d"][0]) if has_td else None))
    out.birge = _birge(out.segments)
    for a, b in itertools.combinations(out.segments, 2):
        sa = {"R_MI": a.sigma_R, "p_MI": a.sigma_p,
              "t_d": None if a.sigma_t_d is None else np.array([a.sigma_t_d])}
        sb = {"R_MI": b.sigma_R, "p_MI": b.sigma_p,
              "t_d": None if b.sigma_t_d is None else np.array([b.sigma_t_d])}
        for name, v in _z(a, b, sa, sb).items():
            out.max_z[name] = max(out.max_z.get(name, 0.0), v)
    return out


def _birge(segs: list[SegmentEstimate]) -> dict[str, float]:
    """``sqrt(chi2 / dof)`` of the segments about their inverse-variance weighted mean."""
    out = {}
    R0 = segs[0].R_MI
    vals = {"R_MI": [so3.log(R0.T @ s.R_MI) for s in segs], "p_MI": [s.p_MI for s in segs]}
    sig = {"R_MI": [s.sigma_R for s in segs], "p_MI": [s.sigma_p for s in segs]}
    if all(s.t_d is not None for s in segs):
        vals["t_d"] = [np.array([s.t_d]) for s in segs]
        sig["t_d"] = [np.array([s.sigma_t_d]) for s in segs]
    for name in vals:
        x, sg = np.array(vals[name]), np.array(sig[name])
        w = 1.0 / sg**2
        mean = (w * x).sum(axis=0) / w.sum(axis=0)
        chi2 = float((w * (x - mean) ** 2).sum())
        out[name] = float(np.sqrt(chi2 / ((len(segs) - 1) * x.shape[1])))
    return out


@dataclass
class Sensitivity:
    """How far the answer moves under scaled IMU noise densities.

    Attributes:
        shift: factor -> parameter -> |change| per component beyond what the reweighting
            explains by chance (parameter units; rotation and gravity in rad).
        moved: factor -> parameter -> largest |change| / the statistical sigma.
    """

    shift: dict[str, dict[str, Array]] = field(default_factory=dict)  # beyond chance
    raw: dict[str, dict[str, Array]] = field(default_factory=dict)  # |change|
    moved: dict[str, dict[str, float]] = field(default_factory=dict)
    note: str = ""

    def systematic(self, param: str) -> Array | None:
        """Per component, the largest shift over the factors: the uncertainty the unknown
        noise densities add (None when not computed)."""
        shifts = [d[param] for d in self.shift.values() if param in d]
        return np.max(np.stack(shifts), axis=0) if shifts else None

    def largest_move(self, param: str) -> Array | None:
        """Per component, the largest plain |change| over the factors (None: not computed)."""
        moves = [d[param] for d in self.raw.values() if param in d]
        return np.max(np.stack(moves), axis=0) if moves else None

    def to_dict(self, total_sigma: dict[str, Array] | None = None) -> dict[str, Any]:
        d: dict[str, Any] = {"moved_statistical_sigmas": {
            f: {k: round(v, 3) for k, v in m.items()} for f, m in self.moved.items()}}
        if total_sigma:
            d["moved_sigmas"] = {
                f: {k: round(float(np.max(v / total_sigma[k])), 3) for k, v in sh.items()
                    if k in total_sigma} for f, sh in self.raw.items()}
        if self.note:
            d["note"] = self.note
        return d


#: A noise-sensitivity refit stops stepping once a step moves no parameter by this many sigmas.
SETTLED_SIGMA = 0.1

#: Result parameter -> covariance block of the position stage.
_BLOCKS = {"R_MI": "rotation", "p_MI": "translation", "t_d": "time_offset",
           "gyro_bias": "gyro_bias", "accel_bias": "accel_bias", "gravity": "gravity"}


def _shifts(alt: PositionResult,
            pos: PositionResult) -> tuple[dict[str, Array], dict[str, Array]]:
    """Per parameter and component, the part of |alt - pos| that the reweighting itself does
    not explain, and the plain |alt - pos|. Two estimates from the same data under different
    weights differ by chance with variance about |var_alt - var| (Hausman); only the excess is a
    systematic shift."""
    raw = {"R_MI": so3.log(pos.R_MI.T @ alt.R_MI), "p_MI": alt.p_MI - pos.p_MI,
           "gyro_bias": alt.gyro_bias_mean - pos.gyro_bias_mean,
           "accel_bias": alt.accel_bias_mean - pos.accel_bias_mean,
           "gravity": np.asarray(gtsam.Unit3(pos.g_dir).localCoordinates(gtsam.Unit3(alt.g_dir)))}
    if "time_offset" in pos.cov:
        raw["t_d"] = np.array([alt.delta - pos.delta])
    excess = {}
    for name, d in raw.items():
        block = _BLOCKS[name]
        chance = 0.0
        if block in pos.cov and block in alt.cov:
            chance = np.abs(np.diag(alt.cov[block]) - np.diag(pos.cov[block]))
        excess[name] = np.sqrt(np.maximum(d**2 - chance, 0.0))
    return excess, {k: np.abs(v) for k, v in raw.items()}


def noise_sensitivity(s: PreparedSession, model: Model, pos: PositionResult,
                      factors: tuple[float, ...] = (3.0, 1.0 / 3.0),
                      max_iterations: int = 30, one_step: bool | int = 3,
                      priors: list[Prior] | None = None) -> Sensitivity:
    """Refit with the IMU noise densities scaled, as a full run given them would land: the mocap
    noise chosen again at the solution, then three Gauss-Newton steps between which the mocap
    levels and the robust weights follow the innovations (``one_step``: other step counts;
    ``False``: LM rounds). On EuRoC V2_03 this lands within 0.1 mm and 0.003 deg of a full
    rerun with the scaled densities, at a seventh of its cost.

    User priors come from earlier sessions calibrated under the same densities, so their
    sigmas scale with them: the balance between prior and data stays, and a prior that
    disagrees with a short session by chance does not pass for a systematic."""
    out = Sensitivity()
    sig = _sigmas(pos)
    everything = np.arange(pos.windows.count)

    def settled(a: Theta, b: Theta) -> bool:
        # A step below a tenth of a sigma: the rest of the way is smaller still.
        return max(_z(a, b, sig, None).values()) < SETTLED_SIGMA

    def refit(f: float) -> PositionResult:
        scaled = pos.noise.imu_scaled(f)
        # As a run given these densities would: the mocap noise chosen again too.
        scaled_priors = [replace(p, sigma=np.asarray(p.sigma) * f) for p in priors or []]
        return run_position_stage(s, model, scaled, pos.windows, _init(pos, everything),
                                  scaled_priors, robust=False, adapt_noise=True,
                                  weights=pos.weights, max_iterations=max_iterations,
                                  one_step=one_step, reweight=True, settled=settled)

    for f in factors:
        interrupt.check()
        try:
            alt = refit(f)
        except Interrupted:
            raise
        except (CalibrationError, np.linalg.LinAlgError, RuntimeError) as err:
            out.note = f"noise x{f:.3g}: refit failed ({err})"
            continue
        key = f"x{f:.3g}"
        out.shift[key], out.raw[key] = _shifts(alt, pos)
        out.moved[key] = _z(alt, pos, sig, None)
    return out
