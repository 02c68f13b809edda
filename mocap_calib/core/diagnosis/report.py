"""What a diagnosis reports: every step's candidates and residuals, what was found, what was
implausible, what stays unexplained; typed and versioned (``kind: diagnosis``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.diagnosis.predict import ResidualAnalysis
from mocap_calib.core.model.effects import EFFECTS
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.result.sections import Degradation
from mocap_calib.core.stages.figures import ResidualSeries
from mocap_calib.core.versioned import check_kind, header

Array = NDArray[np.float64]

REPORT_KIND = "diagnosis"
#: 2: every candidate's statistic is its score test at the step's solution; the refitted
#: ones' likelihood ratio and Wald are the confirmation (``confirm_*``, ``refuted``).
REPORT_VERSION = 2


@dataclass
class CandidateScore:
    """One candidate's test.

    Attributes:
        statistic, log10_p: the score test at the step's solution (the smaller evidence of
            its model-based and windows' sandwich statistics).
        delta_chi2, scale, wald, confirm_statistic, confirm_log10_p: the refit's confirmation
            (NaN where it was not refitted): the cost drop, the noise scale, the robust Wald
            statistic, and the smaller of the noise-scaled likelihood ratio and the Wald.
        significant: the score test passes and, where refitted, the refit confirms it and
            lowers the measurement-domain residual.
        residual_drop: relative low-band residual drop on the effect's sensor (0.1 = 10 %;
            NaN where not refitted).
        params, sigma: the refit's estimate and 1-sigma (not refitted: the score test's
            one-step estimate, no sigma).
        refuted: why a significant score was not confirmed by the refit.
        implausible: the one-line reason when its magnitude is outside the plausible range.
    """

    effect: str
    dof: int
    delta_chi2: float
    scale: float
    statistic: float
    log10_p: float
    significant: bool
    residual_drop: float
    params: object = None
    sigma: object = None
    wald: float = float("nan")
    implausible: str | None = None
    takes: list[dict[str, Any]] | None = None  # several takes: each one's own test
    confirm_statistic: float = float("nan")
    confirm_log10_p: float = float("nan")
    refuted: str | None = None

    def to_dict(self) -> dict[str, Any]:
        d = {"effect": self.effect, "dof": self.dof, "statistic": round(self.statistic, 3),
             "log10_p": round(self.log10_p, 3), "significant": self.significant}
        if not np.isnan(self.confirm_statistic):
            d["refit"] = {"delta_chi2": round(self.delta_chi2, 3),
                          "noise_scale": round(self.scale, 4),
                          "wald_robust": _num(self.wald, 3),
                          "statistic": round(self.confirm_statistic, 3),
                          "log10_p": round(self.confirm_log10_p, 3),
                          "residual_drop": _num(self.residual_drop, 4)}
        if self.refuted:
            d["refuted"] = self.refuted
        if self.implausible:
            d["implausible"] = self.implausible
        if self.takes:
            d["takes"] = self.takes
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CandidateScore:
        """Either version: a version 1 candidate's test is its refit's."""
        r = d.get("refit") or (d if "delta_chi2" in d else {})

        def num(x: Any) -> float:
            return float("nan") if x is None else float(x)

        return cls(str(d["effect"]), int(d["dof"]), num(r.get("delta_chi2")),
                   num(r.get("noise_scale")), float(d["statistic"]), float(d["log10_p"]),
                   bool(d["significant"]), num(r.get("residual_drop")),
                   wald=num(r.get("wald_robust")), implausible=d.get("implausible"),
                   takes=d.get("takes"),
                   confirm_statistic=num(r.get("statistic")) if "refit" in d else float("nan"),
                   confirm_log10_p=num(r.get("log10_p")) if "refit" in d else float("nan"),
                   refuted=d.get("refuted"))


def _num(x: float, digits: int) -> float | None:
    """A figure for the file (None: not computed)."""
    return None if np.isnan(x) else round(float(x), digits)


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
                          "dof": best.dof, "log10_p": round(best.log10_p, 3),
                          "refit_statistic": round(best.confirm_statistic, 3),
                          "refit_log10_p": round(best.confirm_log10_p, 3),
                          **({"takes": best.takes} if best.takes else {})}
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
    implausible: list[dict[str, Any]] = field(default_factory=list)
    unexplained: dict[str, Any] | None = None
    degraded: list[Degradation] = field(default_factory=list)

    @property
    def verdict(self) -> str:
        found = "none" if not self.found else "+".join(self.found)
        return found + ("; residual unexplained" if self.unexplained else "")

    def to_dict(self) -> dict[str, Any]:
        return {
            **header(REPORT_KIND, REPORT_VERSION),
            "found": list(self.found),
            "implausible": list(self.implausible),
            "unexplained": self.unexplained,
            "verdict": self.verdict,
            "start_model": self.start_model,
            "final_model": self.final_model,
            "test": {"kind": "score test at each step's solution (the weaker of model-based "
                             "and windows' sandwich), Bonferroni over candidates; the one "
                             "added confirmed by its refit: min(noise-scaled likelihood "
                             "ratio, robust Wald) beyond the same threshold and a lower "
                             "low-band residual",
                     "threshold_log10_p": round(self.threshold_log10_p, 3)},
            "steps": [s.to_dict() for s in self.steps],
            "final_residuals": self.final_residuals.to_dict(),
            "final_calibration": self.final.to_dict(),
            **({"degraded": [x.to_dict() for x in self.degraded]} if self.degraded else {}),
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
                   float(d.get("seconds", 0.0)), list(d.get("implausible") or []),
                   d.get("unexplained"),
                   [Degradation.from_dict(x) for x in d.get("degraded") or []])


