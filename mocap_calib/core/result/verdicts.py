"""Sections of a calibration result that judge it: plausibility, the segments' and takes'
consistency, the sensitivity to the noise models, the score tests of the effects the model
lacks, and (``--model auto``) why the model was chosen.

Each section is built once, by the pass that knows it, and never changed afterwards; it holds
the numbers the result file shows (rounded where the file rounds). ``to_dict``/``from_dict``
give the file's plain data (``docs/conventions.md``), called only by
:class:`~mocap_calib.core.result.calibration.CalibrationResult`'s own.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from mocap_calib.core.model.parameters import COMPARED, Parameter
from mocap_calib.core.result.estimate import (
    Estimate,
    by_symbol_map,
    plain,
    read_sigma,
    read_value,
    symbol_map,
)


@dataclass(frozen=True)
class PlausibilityFigures:
    """The figures the plausibility gate checked (None: not checked), rounded as shown."""

    gyro_bias_max_rad_s: float | None = None
    accel_bias_max_m_s2: float | None = None
    lever_arm_m: float | None = None
    up_axis: str | None = None
    tilt_deg: float | None = None
    mocap_noise_mm_deg: tuple[float, float] | None = None
    clock_fine_minus_coarse_s: float | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is not None:
                out[f.name] = list(v) if isinstance(v, tuple) else v
        return out

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> PlausibilityFigures:
        known = {f.name for f in fields(cls)}
        kw = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k in known}
        return cls(**kw)


@dataclass(frozen=True)
class Plausibility:
    """The physical checks: the failed ones (one line each) and the figures checked."""

    failed: tuple[str, ...]
    figures: PlausibilityFigures

    @property
    def verdict(self) -> str:
        return "implausible" if self.failed else "plausible"

    def to_dict(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "failed": list(self.failed),
                "figures": self.figures.to_dict()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> Plausibility | None:
        if not d:
            return None
        return cls(tuple(d.get("failed") or ()),
                   PlausibilityFigures.from_dict(d.get("figures") or {}))


@dataclass(frozen=True)
class SegmentRecord:
    """One segment (or take) calibrated on its own: its span (``start_s`` on the clock of
    ``take``, ``end_s`` on that of ``end_take``; takes counted from 1, None with one take)
    and its answer for the compared parameters."""

    start_s: float
    end_s: float
    estimates: Mapping[Parameter, Estimate]
    take: int | None = None
    end_take: int | None = None

    def to_dict(self) -> dict[str, Any]:
        ests = [(p, self.estimates.get(p, Estimate())) for p in COMPARED]
        return {**({"take": self.take} if self.take is not None else {}),
                **({"end_take": self.end_take} if self.end_take not in (None, self.take)
                   else {}),
                "start_s": self.start_s, "end_s": self.end_s,
                **{p.value_key[-1]: plain(p, e.value) for p, e in ests},
                "sigma": {p.sigma_key: plain(p, e.sigma) for p, e in ests}}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SegmentRecord:
        sig = d.get("sigma") or {}
        take = d.get("take")
        return cls(float(d["start_s"]), float(d["end_s"]),
                   {p: Estimate(read_value(p, d.get(p.value_key[-1]), p.value_key[-1]),
                                read_sigma(p, sig.get(p.sigma_key), f"sigma.{p.sigma_key}"))
                    for p in COMPARED}, take, d.get("end_take", take))


@dataclass(frozen=True)
class ConsistencyReport:
    """The segments (or takes) calibrated on their own and how well they agree, per compared
    parameter: largest pairwise |difference| / combined sigma, Birge ratio, the factor the
    statistical sigma was grown by, chi-square p-value (rounded as the file shows them);
    ``note``: why there are none; ``takes``: the takes' own comparison (several takes)."""

    segments: tuple[SegmentRecord, ...] = ()
    max_pairwise_z: Mapping[Parameter, float] = field(default_factory=dict)
    birge_ratio: Mapping[Parameter, float] = field(default_factory=dict)
    sigma_factor: Mapping[Parameter, float] = field(default_factory=dict)
    chi2_p_value: Mapping[Parameter, float] = field(default_factory=dict)
    note: str = ""
    takes: ConsistencyReport | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"segments": [s.to_dict() for s in self.segments],
                "max_pairwise_z": symbol_map(self.max_pairwise_z),
                "birge_ratio": symbol_map(self.birge_ratio),
                "sigma_factor": symbol_map(self.sigma_factor),
                "chi2_p_value": symbol_map(self.chi2_p_value),
                **({"note": self.note} if self.note else {}),
                **({"takes": self.takes.to_dict()} if self.takes is not None else {})}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> ConsistencyReport | None:
        if not d:
            return None
        return cls(tuple(SegmentRecord.from_dict(s) for s in d.get("segments") or ()),
                   by_symbol_map(d.get("max_pairwise_z")), by_symbol_map(d.get("birge_ratio")),
                   by_symbol_map(d.get("sigma_factor")), by_symbol_map(d.get("chi2_p_value")),
                   str(d.get("note", "")), cls.from_dict(d.get("takes")))


@dataclass(frozen=True)
class SensitivityReport:
    """How far the answer moves under the other noise models.

    Attributes:
        moved_statistical: alternative -> parameter -> largest |change| / statistical sigma.
        moved: the same in reported sigmas (None before the sigmas were set).
        mocap_noise_model: the correlated mocap model fitted, when one was (time constant,
            fraction, likelihood gain over white noise; rounded to 4 decimals).
        note: why an alternative is missing.
    """

    moved_statistical: Mapping[str, Mapping[Parameter, float]] = field(default_factory=dict)
    moved: Mapping[str, Mapping[Parameter, float]] | None = None
    mocap_noise_model: Mapping[str, float] | None = None
    note: str = ""

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"moved_statistical_sigmas": {
            f: symbol_map(m) for f, m in self.moved_statistical.items()}}
        if self.moved is not None:
            d["moved_sigmas"] = {f: symbol_map(m) for f, m in self.moved.items()}
        if self.mocap_noise_model:
            d["mocap_noise_model"] = dict(self.mocap_noise_model)
        if self.note:
            d["note"] = self.note
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> SensitivityReport | None:
        if not d:
            return None
        moved = d.get("moved_sigmas")
        return cls({f: by_symbol_map(m) for f, m in
                    (d.get("moved_statistical_sigmas") or {}).items()},
                   None if moved is None else {f: by_symbol_map(m) for f, m in moved.items()},
                   d.get("mocap_noise_model"), str(d.get("note", "")))


@dataclass(frozen=True)
class EffectTest:
    """One effect's score test at the solution (statistic and log10 p rounded to 2
    decimals); ``one_step_estimate`` in the effect's file form; ``implausible``: why its
    magnitude is not plausible (None: plausible)."""

    effect: str
    statistic: float
    dof: int
    log10_p: float
    one_step_estimate: Any
    significant: bool
    implausible: str | None = None

    @property
    def plausible(self) -> bool:
        return self.implausible is None

    def to_dict(self) -> dict[str, Any]:
        return {"effect": self.effect, "statistic": self.statistic, "dof": self.dof,
                "log10_p": self.log10_p, "one_step_estimate": self.one_step_estimate,
                "significant": self.significant, "plausible": self.plausible,
                **({"implausible": self.implausible} if self.implausible else {})}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> EffectTest:
        return cls(str(d["effect"]), float(d["statistic"]), int(d["dof"]),
                   float(d["log10_p"]), d.get("one_step_estimate"), bool(d["significant"]),
                   d.get("implausible"))


@dataclass(frozen=True)
class EffectTests:
    """Score tests of the effects the model lacks: family-wise ``alpha``, every candidate in
    order of evidence, the effects ``shown`` (significant and plausible), and the windows of
    the session and of the tests."""

    alpha: float
    candidates: tuple[EffectTest, ...]
    shown: tuple[str, ...]
    windows: int
    windows_tested: int

    def to_dict(self) -> dict[str, Any]:
        return {"alpha": self.alpha, "candidates": [c.to_dict() for c in self.candidates],
                "shown": list(self.shown), "windows": self.windows,
                "windows_tested": self.windows_tested}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> EffectTests | None:
        if not d:
            return None
        return cls(float(d["alpha"]), tuple(EffectTest.from_dict(c) for c in d["candidates"]),
                   tuple(d.get("shown") or ()), int(d.get("windows", 0)),
                   int(d.get("windows_tested", 0)))


@dataclass(frozen=True)
class SelectionStep:
    """One step of the diagnosis: the model, the effect added (None: none) and the strongest
    candidates' ``(effect, log10 p)`` (rounded to 2 decimals)."""

    model: str
    added: str | None
    candidates: tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class ModelSelection:
    """``--model auto``: the model chosen and why (``docs/conventions.md``,
    ``model_selection:``); ``implausible``: the diagnosis' own records of the effects its
    plausibility gates refused; ``found_per_take``: with several takes, each one's effects."""

    chosen: str
    method: str
    threshold_log10_p: float
    steps: tuple[SelectionStep, ...]
    implausible: tuple[Mapping[str, Any], ...]
    found_per_take: tuple[tuple[str, ...], ...] | None = None
    requested: str = "auto"

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "requested": self.requested, "chosen": self.chosen, "method": self.method,
            "threshold_log10_p": self.threshold_log10_p,
            "steps": [{"model": s.model, "added": s.added,
                       "candidates": [{"effect": e, "log10_p": p} for e, p in s.candidates]}
                      for s in self.steps],
            "implausible": [dict(x) for x in self.implausible]}
        if self.found_per_take is not None:
            d["found_per_take"] = [list(x) for x in self.found_per_take]
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None) -> ModelSelection | None:
        if not d:
            return None
        per_take = d.get("found_per_take")
        return cls(str(d["chosen"]), str(d.get("method", "")),
                   float(d.get("threshold_log10_p", 0.0)),
                   tuple(SelectionStep(s["model"], s.get("added"),
                                       tuple((c["effect"], c["log10_p"])
                                             for c in s.get("candidates") or ()))
                         for s in d.get("steps") or ()),
                   tuple(dict(x) for x in d.get("implausible") or ()),
                   None if per_take is None else tuple(tuple(x) for x in per_take),
                   str(d.get("requested", "auto")))
