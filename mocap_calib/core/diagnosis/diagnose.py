"""Model diagnosis: find what the calibrated model misses, name it, add it, repeat.

1. Calibrate the starting model (default: the base model, no time offset).
2. Simulate what the IMU should have measured from the mocap through the calibrated model and
   compare with what it measured (:mod:`mocap_calib.core.diagnosis.predict`): residual RMS per
   sensor and axis in a low band, against the noise floor that noise alone gives through the same
   processing, and residual spectra.
3. For every candidate effect (the canonical ones), refit with the effect added and score it
   with a likelihood-ratio test: ``T = (chi2_M - chi2_M+e) / s^2`` against ``chi2_k``
   (``k`` = the effect's parameters), where ``s^2 = max(1, chi2/dof)`` of the extended fit
   absorbs a misjudged overall noise level. The noise model and the robust weights are frozen
   for all fits, so every fit minimises a cost of the same family. The threshold is
   Bonferroni-corrected over the candidates tried.
4. The most significant candidate (smallest p-value) must also *show* in the measurement
   domain: its fit has to lower the low-band residual of the sensor it acts on. It is added,
   and the loop repeats until no candidate passes; then the answer is "none".
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import stats as sps

from mocap_calib.core.calib.clock import search_clock
from mocap_calib.core.calib.pipeline import CalibrationOptions, calibrate
from mocap_calib.core.calib.result import CalibrationResult, ResidualSeries
from mocap_calib.core.calib.session import PreparedSession
from mocap_calib.core.calib.stage_position import PositionInit, PositionResult, run_position_stage
from mocap_calib.core.calib.state import ModelState
from mocap_calib.core.diagnosis.predict import ResidualAnalysis, analyse_residuals
from mocap_calib.core.model.effects import CANONICAL_EFFECTS, EFFECTS, Model
from mocap_calib.core.model.plausible import PlausibleLimits, effect_problem
from mocap_calib.core.model.types import ImuSamples, MocapPoses, NoiseModel
from mocap_calib.core.model.versioned import check_kind, header
from mocap_calib.errors import CalibrationError, InputError

Array = NDArray[np.float64]


REPORT_KIND = "diagnosis"
REPORT_VERSION = 1


@dataclass
class DiagnoseOptions:
    """How to diagnose.

    Attributes:
        start: the starting model (default: base, no time offset).
        candidates: effects to try.
        alpha: family-wise false-alarm rate per step (Bonferroni over the candidates).
        max_steps: most effects to add.
        calibration: options of the underlying calibrations (noise, gravity, windows...).
        cutoff_hz: band of the measurement-domain comparison.
    """

    start: Model = field(default_factory=Model)
    candidates: tuple[str, ...] = CANONICAL_EFFECTS
    alpha: float = 0.01
    max_steps: int = 4
    calibration: CalibrationOptions = field(default_factory=CalibrationOptions)
    cutoff_hz: float = 2.0


@dataclass
class CandidateScore:
    """One candidate's test."""

    effect: str
    dof: int
    delta_chi2: float
    scale: float
    statistic: float
    log10_p: float
    significant: bool
    residual_drop: float  # relative low-band residual drop on the effect's sensor (0.1 = 10 %)
    params: object = None
    sigma: object = None

    def to_dict(self) -> dict[str, Any]:
        return {"effect": self.effect, "dof": self.dof, "delta_chi2": round(self.delta_chi2, 3),
                "noise_scale": round(self.scale, 4), "statistic": round(self.statistic, 3),
                "log10_p": round(self.log10_p, 3), "significant": self.significant,
                "residual_drop": round(self.residual_drop, 4)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CandidateScore:
        return cls(str(d["effect"]), int(d["dof"]), float(d["delta_chi2"]),
                   float(d["noise_scale"]), float(d["statistic"]), float(d["log10_p"]),
                   bool(d["significant"]), float(d["residual_drop"]))


@dataclass
class Residuals:
    """Low-band residual RMS per sensor and axis with the noise floor."""

    gyro_rms: Array
    gyro_floor: Array
    accel_rms: Array
    accel_floor: Array
    analysis: ResidualAnalysis | None = None
    stored: dict[str, Any] | None = field(default=None, repr=False)  # as read from a file

    @classmethod
    def of(cls, ra: ResidualAnalysis) -> Residuals:
        return cls(ra.gyro_rms, ra.gyro_floor, ra.accel_rms, ra.accel_floor, ra)

    def ratio(self, sensor: str) -> float:
        """RMS over axes divided by the floor over axes (1 = at the noise floor)."""
        rms, floor = ((self.gyro_rms, self.gyro_floor) if sensor == "gyro"
                      else (self.accel_rms, self.accel_floor))
        return float(np.sqrt(np.sum(rms**2) / np.sum(floor**2)))

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "gyro_rms": self.gyro_rms.tolist(), "gyro_floor": self.gyro_floor.tolist(),
            "gyro_ratio": round(self.ratio("gyro"), 4),
            "accel_rms": self.accel_rms.tolist(), "accel_floor": self.accel_floor.tolist(),
            "accel_ratio": round(self.ratio("accel"), 4)}
        if self.analysis is not None:
            d["cutoff_hz"] = self.analysis.cutoff_hz
            d["power_over_floor_by_band"] = self.analysis.band_ratios()
        elif self.stored is not None:
            d.update({k: v for k, v in self.stored.items() if k not in d})
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Residuals:
        """The figures of :meth:`to_dict` (the residual series themselves are not stored)."""
        return cls(*(np.asarray(d[k], dtype=float)
                     for k in ("gyro_rms", "gyro_floor", "accel_rms", "accel_floor")),
                   stored=d)


@dataclass
class DiagnoseStep:
    """One step: the model, the candidates' scores, and what was added (if anything)."""

    model: str
    residuals: Residuals
    chi2: float
    dof: int
    candidates: list[CandidateScore]
    added: str | None = None
    added_params: object = None
    added_sigma: object = None
    residuals_after: Residuals | None = None
    series: dict[str, ResidualSeries] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"model": self.model, "chi2": round(self.chi2, 3), "dof": self.dof,
                             "residuals": self.residuals.to_dict(),
                             "candidates": [c.to_dict() for c in self.candidates]}
        if self.added is not None:
            best = next(c for c in self.candidates if c.effect == self.added)
            d["added"] = {"effect": self.added, EFFECTS[self.added].param: self.added_params,
                          "sigma": self.added_sigma, "statistic": round(best.statistic, 3),
                          "dof": best.dof, "log10_p": round(best.log10_p, 3)}
            if self.residuals_after is not None:
                d["residuals_after"] = self.residuals_after.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DiagnoseStep:
        added = d.get("added") or {}
        name = added.get("effect")
        after = d.get("residuals_after")
        return cls(str(d["model"]), Residuals.from_dict(d["residuals"]), float(d["chi2"]),
                   int(d["dof"]), [CandidateScore.from_dict(c) for c in d["candidates"]],
                   added=name, added_params=added.get(EFFECTS[name].param) if name else None,
                   added_sigma=added.get("sigma"),
                   residuals_after=None if after is None else Residuals.from_dict(after))


@dataclass
class DiagnoseReport:
    """The outcome: effects found in order, every step, and the final calibration."""

    found: list[str]
    start_model: str
    final_model: str
    steps: list[DiagnoseStep]
    final: CalibrationResult
    final_residuals: Residuals
    threshold_log10_p: float
    notes: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def verdict(self) -> str:
        return "none" if not self.found else "+".join(self.found)

    def to_dict(self) -> dict[str, Any]:
        return {
            **header(REPORT_KIND, REPORT_VERSION),
            "found": list(self.found),
            "verdict": self.verdict,
            "start_model": self.start_model,
            "final_model": self.final_model,
            "test": {"kind": "likelihood ratio, noise-scaled, Bonferroni over candidates",
                     "threshold_log10_p": round(self.threshold_log10_p, 3)},
            "steps": [s.to_dict() for s in self.steps],
            "final_residuals": self.final_residuals.to_dict(),
            "final_calibration": self.final.to_dict(),
            "notes": list(self.notes),
            "seconds": round(self.seconds, 2),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DiagnoseReport:
        """Inverse of :meth:`to_dict` (figures only: no residual series).

        Raises:
            KindError: not a diagnosis report, or a newer version.
            KeyError, ValueError, TypeError: a malformed report.
        """
        check_kind(d, REPORT_KIND, REPORT_VERSION)
        return cls(list(d["found"]), str(d["start_model"]), str(d["final_model"]),
                   [DiagnoseStep.from_dict(x) for x in d["steps"]],
                   CalibrationResult.from_dict(d["final_calibration"]),
                   Residuals.from_dict(d["final_residuals"]),
                   float(d["test"]["threshold_log10_p"]), list(d.get("notes") or []),
                   float(d.get("seconds", 0.0)))


def plausibility(effect: str, value: object) -> str | None:
    """A one-line warning when an effect's estimate is outside its plausible range."""
    return effect_problem(effect, value, PlausibleLimits())


def _log10_sf(t: float, k: int) -> float:
    """log10 P(chi2_k > t), finite far into the tail (Wilson-Hilferty when scipy underflows)."""
    lp = float(sps.chi2.logsf(t, k))
    if np.isfinite(lp):
        return lp / np.log(10.0)
    z = ((t / k) ** (1.0 / 3.0) - (1.0 - 2.0 / (9.0 * k))) / np.sqrt(2.0 / (9.0 * k))
    return float(sps.norm.logsf(z) / np.log(10.0))


def _sensor_of(effect: str) -> str:
    e = EFFECTS[effect]
    return e.sensor if e.sensor in ("gyro", "accel") else ("accel" if effect ==
                                                            "gravity_magnitude" else "both")


def _state(pos: PositionResult, model: Model, t_mid: float) -> ModelState:
    return ModelState.from_position(pos, model, t_mid)


def _drop(before: Residuals, after: Residuals, sensor: str) -> float:
    if sensor == "both":
        return max(_drop(before, after, "gyro"), _drop(before, after, "accel"))
    return 1.0 - after.ratio(sensor) / before.ratio(sensor)


def diagnose(imu: ImuSamples, mocap: MocapPoses, options: DiagnoseOptions | None = None,
             progress: Callable[[str], None] | None = None) -> DiagnoseReport:
    """Run the diagnosis loop (see the module docstring).

    Args:
        imu: raw IMU samples; mocap: marker poses.
        options: see :class:`DiagnoseOptions`.
        progress: called with one-line messages.
    """
    opts = options or DiagnoseOptions()
    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    notes: list[str] = []
    model = opts.start
    # The starting fit only seeds the diagnosis: no segment or noise checks, and a model that
    # misses an effect may well look implausible (that is what the diagnosis is for).
    cal_opts = replace(opts.calibration, model=model, adapt_noise=False, consistency_segments=0,
                       sensitivity=False, accept_implausible=True)

    say(f"fitting the starting model {model}")
    try:
        start = calibrate(imu, mocap, cal_opts)
    except InputError:  # the streams may not even overlap without the offset
        if model.has("time_offset"):
            raise
        model = model.with_effect("time_offset")
        notes.append("the raw stamps do not overlap: time_offset added before the diagnosis")
        cal_opts = replace(cal_opts, model=model)
        start = calibrate(imu, mocap, cal_opts)
    ex = start.diagnostics.trace
    s: PreparedSession = ex.session
    noise: NoiseModel = ex.noise_used
    t_mid = float(ex.model_state.t_mid)
    windows = ex.windows
    weights = ex.weights
    coarse_delta = None

    def fit(m: Model, base: PositionResult, extra: dict[str, Array], nz: NoiseModel,
            adapt: bool = False) -> PositionResult:
        init = PositionInit(
            R_MI=base.R_MI, p_MI=base.p_MI, g_dir=base.g_dir, g_mag=base.g_mag,
            delta=base.delta, gyro_bias=base.gyro_bias_mean, accel_bias=base.accel_bias_mean,
            effects={**base.effects, **extra}, knots=base.knots)
        if "time_offset" in extra:
            init.delta = float(extra["time_offset"][0])
        return run_position_stage(s, m, nz, windows, init, robust=False, adapt_noise=adapt,
                                  weights=weights, max_iterations=opts.calibration.max_iterations)

    # The current fit, as a PositionResult (refit the start model with frozen weights so every
    # later comparison uses exactly the same cost).
    # From the model state, not the public result: that holds None for what is unobservable.
    st0: ModelState = ex.model_state
    g_mag0 = float(np.linalg.norm(st0.g_W))
    init0 = PositionInit(
        R_MI=st0.R_MI, p_MI=st0.p_MI, g_dir=st0.g_W / g_mag0, g_mag=g_mag0, delta=st0.delta,
        gyro_bias=st0.bias[:, 0:3].mean(axis=0), accel_bias=st0.bias[:, 3:6].mean(axis=0),
        effects=dict(st0.effects), knots=st0.bias)
    # Every step first re-estimates the mocap noise level with the current model (rarely known
    # well; a missing effect inflates it, so it is redone after each effect is added); the
    # candidates of the step are then fitted with that noise level frozen.
    current = run_position_stage(s, model, noise, windows, init0, robust=False,
                                 adapt_noise=True, weights=weights)
    noise = current.noise
    cur_res = Residuals.of(analyse_residuals(s, _state(current, model, t_mid), noise,
                                             cutoff_hz=opts.cutoff_hz))
    found: list[str] = []
    steps: list[DiagnoseStep] = []
    threshold = 0.0
    for _step in range(opts.max_steps):
        todo = [c for c in opts.candidates if not model.has(c)]
        if not todo:
            break
        threshold = float(np.log10(opts.alpha / len(todo)))
        scores: list[CandidateScore] = []
        fits: dict[str, tuple[PositionResult, Residuals]] = {}
        for cand in todo:
            say(f"step {len(steps) + 1}: trying {cand}")
            m = model.with_effect(cand)
            extra: dict[str, Array] = {}
            try:
                if cand == "time_offset":
                    if coarse_delta is None:
                        coarse_delta = search_clock(
                            s.u, s.gyro, s.accel, s.tau, s.R_WM, s.p_WM,
                            s.clock_shift).time_offset + s.clock_shift
                    extra["time_offset"] = np.array([coarse_delta])
                f = fit(m, current, extra, noise)
            except (CalibrationError, np.linalg.LinAlgError, RuntimeError) as err:
                # A candidate that cannot be fitted (GTSAM raises RuntimeError on an
                # indeterminate system) is not the answer.
                notes.append(f"step {len(steps) + 1}: {cand} could not be fitted ({err})")
                continue
            k = EFFECTS[cand].dim
            d = current.cost - f.cost
            scale = max(1.0, f.cost / max(f.dof, 1))
            stat = max(d, 0.0) / scale
            log10_p = _log10_sf(stat, k)
            # The measurement-domain check is only needed where the test is significant.
            res = (Residuals.of(analyse_residuals(s, _state(f, m, t_mid), noise,
                                                  cutoff_hz=opts.cutoff_hz))
                   if log10_p < threshold else cur_res)
            fits[cand] = (f, res)
            eff = EFFECTS[cand]
            if cand == "time_offset":
                params, sig = float(f.delta - s.clock_shift), float(np.sqrt(
                    f.cov["time_offset"][0, 0]))
            elif cand == "gravity_magnitude":
                params, sig = float(f.g_mag), float(np.sqrt(f.cov["gravity_magnitude"][0, 0]))
            else:
                params = eff.report_value(f.effects[cand])
                sig = eff.report_sigma(np.sqrt(np.diag(f.cov[cand])))
            drop = _drop(cur_res, res, _sensor_of(cand))
            scores.append(CandidateScore(cand, k, float(d), float(scale), float(stat), log10_p,
                                         log10_p < threshold and drop > 0.0, float(drop),
                                         params, sig))
        scores.sort(key=lambda c: c.log10_p)
        step = DiagnoseStep(str(model), cur_res, current.cost, current.dof, scores,
                            series={"position": current.series})
        steps.append(step)
        best = next((c for c in scores if c.significant), None)
        if best is None:
            break
        f, res = fits[best.effect]
        step.added = best.effect
        step.added_params = best.params
        step.added_sigma = best.sigma
        step.residuals_after = res
        say(f"step {len(steps)}: {best.effect} explains the gap (T = {best.statistic:.1f} on "
            f"{best.dof} dof, log10 p = {best.log10_p:.1f})")
        found.append(best.effect)
        warning = plausibility(best.effect, best.params)
        if warning is not None:
            notes.append(f"step {len(steps)}: {warning}; it probably absorbs something outside "
                         "the candidate list")
        model = model.with_effect(best.effect)
        current = fit(model, f, {}, noise, adapt=True)
        if current.noise != noise:
            noise = current.noise
            cur_res = Residuals.of(analyse_residuals(s, _state(current, model, t_mid), noise,
                                                     cutoff_hz=opts.cutoff_hz))
        else:
            cur_res = res

    say(f"final calibration with {model}")
    final = calibrate(imu, mocap, replace(opts.calibration, model=model, accept_implausible=True))
    fx = final.diagnostics.trace
    final_res = Residuals.of(analyse_residuals(fx.session, fx.model_state, fx.noise_used,
                                               cutoff_hz=opts.cutoff_hz))
    steps.append(DiagnoseStep(str(model), final_res, current.cost, current.dof, [],
                              series={"position": current.series}))
    return DiagnoseReport(found, str(opts.start), str(model), steps, final, final_res, threshold,
                          notes, time.perf_counter() - t0)
