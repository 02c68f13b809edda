"""Typed results: the calibration (``docs/conventions.md`` keys) and what it exposes for
inspection.

A result holds one :class:`~mocap_calib.core.result.estimate.Estimate` per base parameter
(:mod:`mocap_calib.core.model.parameters`) and one typed, immutable section per check
(:mod:`.sections`, :mod:`.verdicts`); each pass builds its section once and the pipeline
combines them with :func:`dataclasses.replace`. :meth:`CalibrationResult.to_dict` /
:meth:`CalibrationResult.from_dict` give the versioned plain-data form that ``io`` writes as
YAML (the only place the file's keys appear); a round trip restores the same data.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.parameters import (
    ACCEL_BIAS,
    COMPARED,
    GRAVITY_DIRECTION,
    GYRO_BIAS,
    PARAMETERS,
    ROTATION,
    TIME_OFFSET,
    TRANSLATION,
    Parameter,
)
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.policy import GRAVITY
from mocap_calib.core.result.estimate import Estimate, SigmaTerms, plain, read_sigma, read_value
from mocap_calib.core.result.prior_report import PriorsReport
from mocap_calib.core.result.sections import (
    ClockSummary,
    Degradation,
    ImuGapsSummary,
    NoiseIdentification,
    SolverFigures,
    TakeResult,
)
from mocap_calib.core.result.state import CalibrationTrace, ModelState
from mocap_calib.core.result.verdicts import (
    ConsistencyReport,
    EffectTests,
    ModelSelection,
    Plausibility,
    SensitivityReport,
)
from mocap_calib.core.stages.figures import ResidualSeries, StageStats
from mocap_calib.core.versioned import check_kind, header
from mocap_calib.errors import InputError

if TYPE_CHECKING:
    from mocap_calib.core.prepare.session import PreparedSession

Array = NDArray[np.float64]

RESULT_VERSION = 1
KIND = "calibration"
#: Keys that identify a calibration file written before files had a ``kind``.
LEGACY_KEYS = ("gyro_bias", "accel_bias", "T_marker_imu", "gravity_in_mocap")


@dataclass
class Diagnostics:
    """What the core exposes for inspection (viz, diagnose): never serialised to YAML."""

    residuals: dict[str, ResidualSeries] = field(default_factory=dict)
    iterations: list[dict[str, Any]] = field(default_factory=list)
    trace: CalibrationTrace | None = None
    #: With several takes, each take's own residuals and trace in input order (the first is
    #: the fields above); empty with one take.
    takes: list[Diagnostics] = field(default_factory=list)


@dataclass(frozen=True)
class CalibrationResult:
    """A calibration, with 1-sigma uncertainties and the figures behind it.

    ``estimates`` holds every base parameter; a value of None marks a parameter the session
    could not determine (see ``unobservable``) or, with several takes, one they do not share
    (each take's own are under ``takes``). A section of None was not computed.
    """

    estimates: Mapping[Parameter, Estimate] = field(default_factory=dict)
    gravity_magnitude: float = GRAVITY
    model: str = "base+time_offset"
    effects: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    unobservable: Mapping[str, str] = field(default_factory=dict)
    stages: tuple[StageStats, ...] = ()
    solver: SolverFigures = field(default_factory=SolverFigures)
    noise: NoiseModel = field(default_factory=NoiseModel)
    notes: tuple[str, ...] = ()
    session: dict[str, Any] = field(default_factory=dict)
    imu_gaps: ImuGapsSummary | None = None
    takes: tuple[TakeResult, ...] = ()
    clock: ClockSummary | None = None
    consistency: ConsistencyReport | None = None
    sensitivity: SensitivityReport | None = None
    plausibility: Plausibility | None = None
    effect_tests: EffectTests | None = None
    model_selection: ModelSelection | None = None
    noise_identification: NoiseIdentification | None = None
    priors: PriorsReport | None = None
    degraded: tuple[Degradation, ...] = ()
    version: int = RESULT_VERSION
    diagnostics: Diagnostics | None = field(default=None, repr=False, compare=False)

    def estimate(self, p: Parameter) -> Estimate:
        return self.estimates.get(p) or Estimate()

    def value(self, p: Parameter) -> Array | None:
        """``p``'s value in the file's form (None: not determined, or not shared)."""
        return self.estimate(p).value

    def sigma(self, p: Parameter) -> Array | None:
        """``p``'s reported 1-sigma (tangent)."""
        return self.estimate(p).sigma

    def with_estimates(self, changed: Mapping[Parameter, Estimate]) -> CalibrationResult:
        return replace(self, estimates={**self.estimates, **changed})

    def with_notes(self, *lines: str) -> CalibrationResult:
        return replace(self, notes=(*self.notes, *lines))

    def with_degraded(self, *entries: Degradation) -> CalibrationResult:
        return replace(self, degraded=(*self.degraded, *entries))

    # The values under the result file's names, for readers outside the core.
    @property
    def gyro_bias(self) -> Array | None:
        return self.value(GYRO_BIAS)

    @property
    def accel_bias(self) -> Array | None:
        return self.value(ACCEL_BIAS)

    @property
    def rotation_wxyz(self) -> Array | None:
        return self.value(ROTATION)

    @property
    def translation(self) -> Array | None:
        return self.value(TRANSLATION)

    @property
    def gravity_in_mocap(self) -> Array | None:
        return self.value(GRAVITY_DIRECTION)

    @property
    def time_offset(self) -> float | None:
        return _scalar(self.value(TIME_OFFSET))

    @property
    def sigma_gyro_bias(self) -> Array | None:
        return self.sigma(GYRO_BIAS)

    @property
    def sigma_accel_bias(self) -> Array | None:
        return self.sigma(ACCEL_BIAS)

    @property
    def sigma_rotation(self) -> Array | None:
        return self.sigma(ROTATION)

    @property
    def sigma_translation(self) -> Array | None:
        return self.sigma(TRANSLATION)

    @property
    def sigma_gravity(self) -> Array | None:
        return self.sigma(GRAVITY_DIRECTION)

    @property
    def sigma_time_offset(self) -> float | None:
        return _scalar(self.sigma(TIME_OFFSET))

    @property
    def R_marker_imu(self) -> Array | None:
        q = self.value(ROTATION)
        return None if q is None else ROTATION.state(q)

    def model_state(self, s: PreparedSession) -> ModelState:
        """The model state a result file describes (constant biases), for a session prepared again.

        Raises:
            InputError: the result lacks a value the state needs (an unobservable parameter).
        """
        missing = [".".join(p.value_key) for p in PARAMETERS.values() if self.value(p) is None]
        if missing:
            raise InputError(f"the result has no value for {', '.join(missing)}; a recording "
                             "without the solver's diagnostics needs the full calibration")
        model = Model.parse(self.model)
        effects: dict[str, Array] = {}
        for eff in model.units:
            if eff.in_effects:
                value = (self.effects.get(eff.name) or {}).get(eff.param)
                effects[eff.name] = eff.zero() if value is None else eff.theta_from_report(value)
        g_dir = np.asarray(self.value(GRAVITY_DIRECTION), dtype=float)
        return ModelState(
            R_MI=ROTATION.state(self.value(ROTATION)),
            p_MI=np.asarray(self.value(TRANSLATION), dtype=float),
            g_W=self.gravity_magnitude * g_dir / np.linalg.norm(g_dir),
            delta=s.clock_shift + float(self.time_offset or 0.0), model=model, effects=effects,
            bias_t=np.array([s.tau[0]]),
            bias=np.r_[self.value(GYRO_BIAS), self.value(ACCEL_BIAS)][None],
            t_mid=0.5 * float(s.u[0] + s.u[-1]))

    def to_dict(self) -> dict[str, Any]:
        """Plain data: ``kind`` and ``version``, then the keys of ``docs/conventions.md``."""
        return {
            **header(KIND, self.version),
            **_values_to_dict(self),
            "sigma": {p.sigma_key: plain(p, self.sigma(p)) for p in PARAMETERS.values()},
            "gravity_magnitude": float(self.gravity_magnitude),
            "model": self.model,
            "effects": self.effects,
            "unobservable": dict(self.unobservable),
            "stages": [s.to_dict() for s in self.stages],
            "solver": self.solver.to_dict(),
            "noise": self.noise.to_dict(),
            **({"noise_identification": self.noise_identification.to_dict()}
               if self.noise_identification is not None else {}),
            "session": self.session,
            "imu_gaps": {} if self.imu_gaps is None else self.imu_gaps.to_dict(),
            **({"takes": [t.to_dict() for t in self.takes]} if self.takes else {}),
            "clock": {} if self.clock is None else self.clock.to_dict(),
            "consistency": _or_empty(self.consistency),
            "sensitivity": _or_empty(self.sensitivity),
            "plausibility": _or_empty(self.plausibility),
            "uncertainty": {p.symbol: e.terms.to_dict() for p, e in _judged(self)},
            "effect_tests": _or_empty(self.effect_tests),
            **({"model_selection": self.model_selection.to_dict()}
               if self.model_selection is not None else {}),
            **({"priors": self.priors.to_dict()} if self.priors is not None else {}),
            **({"degraded": [x.to_dict() for x in self.degraded]} if self.degraded else {}),
            "notes": list(self.notes),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CalibrationResult:
        """Inverse of :meth:`to_dict`; raises ``KeyError``/``ValueError`` on a malformed dict
        (:class:`~mocap_calib.core.versioned.KindError` for another kind of file or a newer
        version)."""
        if "kind" not in d and any(k in d for k in LEGACY_KEYS):
            missing = [k for k in LEGACY_KEYS if k not in d]
            if missing:
                raise KeyError(f"missing key '{missing[0]}'; is this a mocap-calib result file?")
        version = check_kind(d, KIND, RESULT_VERSION, legacy=LEGACY_KEYS)
        for k in LEGACY_KEYS:
            if k not in d:
                raise KeyError(f"missing key '{k}'")
        for key in ("T_marker_imu", "sigma"):
            if not isinstance(d.get(key) or {}, dict):
                raise ValueError(f"'{key}' must be a mapping of keys to values")
        return cls(
            estimates=_estimates_from_dict(d),
            gravity_magnitude=float(d.get("gravity_magnitude", GRAVITY)),
            model=(d["model"] if isinstance(d.get("model"), str)
                   else "+".join(d.get("model") or ["base"])),
            effects=dict(d.get("effects") or {}),
            unobservable=dict(d.get("unobservable") or {}),
            stages=tuple(StageStats.from_dict(s) for s in d.get("stages") or []),
            solver=SolverFigures.from_dict(d.get("solver")),
            noise=NoiseModel.from_dict(d.get("noise") or {}),
            noise_identification=NoiseIdentification.from_dict(d.get("noise_identification")),
            notes=tuple(d.get("notes") or []),
            session=dict(d.get("session") or {}),
            imu_gaps=ImuGapsSummary.from_dict(d.get("imu_gaps")),
            takes=tuple(TakeResult.from_dict(t) for t in d.get("takes") or []),
            clock=ClockSummary.from_dict(d.get("clock") or {}),
            consistency=ConsistencyReport.from_dict(d.get("consistency")),
            sensitivity=SensitivityReport.from_dict(d.get("sensitivity")),
            plausibility=Plausibility.from_dict(d.get("plausibility")),
            effect_tests=EffectTests.from_dict(d.get("effect_tests")),
            model_selection=ModelSelection.from_dict(d.get("model_selection")),
            priors=PriorsReport.from_dict(d.get("priors")),
            degraded=tuple(Degradation.from_dict(x) for x in d.get("degraded") or []),
            version=version,
        )


def _scalar(a: Array | None) -> float | None:
    return None if a is None else float(np.asarray(a).ravel()[0])


def _or_empty(section: Any) -> dict[str, Any]:
    return {} if section is None else section.to_dict()


#: The order of ``uncertainty:``: the compared parameters first, then the rest.
UNCERTAINTY_ORDER: tuple[Parameter, ...] = (
    *COMPARED, *(p for p in PARAMETERS.values() if not p.compared))


def _judged(r: CalibrationResult) -> list[tuple[Parameter, Estimate]]:
    """The parameters whose sigma the verdict set, with their estimates, in file order."""
    return [(p, r.estimate(p)) for p in UNCERTAINTY_ORDER if r.estimate(p).terms is not None]


def _values_to_dict(r: CalibrationResult) -> dict[str, Any]:
    """The values under their file keys (nested where the key is), in registry order."""
    out: dict[str, Any] = {}
    for p in PARAMETERS.values():
        *outer, last = p.value_key
        node = out
        for k in outer:
            node = node.setdefault(k, {})
        node[last] = plain(p, r.value(p))
    return out


def _estimates_from_dict(d: dict[str, Any]) -> dict[Parameter, Estimate]:
    sig = d.get("sigma") or {}
    unc = d.get("uncertainty") or {}
    out = {}
    for p in PARAMETERS.values():
        node: Any = d
        for k in p.value_key:
            node = (node or {}).get(k)
        skey = p.sigma_key
        terms = unc.get(p.symbol)
        out[p] = Estimate(read_value(p, node, ".".join(p.value_key)),
                          read_sigma(p, sig.get(skey), f"sigma.{skey}"),
                          None if not terms else SigmaTerms.from_dict(terms))
    return out
