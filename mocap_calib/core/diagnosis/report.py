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
REPORT_VERSION = 1


@dataclass
class CandidateScore:
    """One candidate's test.

    Attributes:
        statistic: the smaller of the noise-scaled likelihood ratio and the Wald statistic
            with the sandwich covariance (robust when the noise model is off).
        significant: passes the test and lowers the measurement-domain residual.
        implausible: the one-line reason when its magnitude is outside the plausible range.
    """

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
    wald: float = 0.0
    implausible: str | None = None
    takes: list[dict[str, Any]] | None = None  # several takes: each one's own test

    def to_dict(self) -> dict[str, Any]:
        d = {"effect": self.effect, "dof": self.dof, "delta_chi2": round(self.delta_chi2, 3),
             "noise_scale": round(self.scale, 4),
             "wald_robust": None if np.isnan(self.wald) else round(self.wald, 3),
             "statistic": round(self.statistic, 3), "log10_p": round(self.log10_p, 3),
             "significant": self.significant, "residual_drop": round(self.residual_drop, 4)}
        if self.implausible:
            d["implausible"] = self.implausible
        if self.takes:
            d["takes"] = self.takes
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CandidateScore:
        return cls(str(d["effect"]), int(d["dof"]), float(d["delta_chi2"]),
                   float(d["noise_scale"]), float(d["statistic"]), float(d["log10_p"]),
                   bool(d["significant"]), float(d["residual_drop"]),
                   wald=float("nan") if d.get("wald_robust") is None
                   else float(d["wald_robust"]), implausible=d.get("implausible"),
                   takes=d.get("takes"))


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
            "test": {"kind": "min(noise-scaled likelihood ratio, robust Wald), Bonferroni over "
                             "candidates",
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


