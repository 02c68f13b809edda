"""Typed results: the calibration (``docs/conventions.md`` keys) and what it exposes for
inspection.

:meth:`CalibrationResult.to_dict` / :meth:`CalibrationResult.from_dict` give the versioned
plain-data form that ``io`` writes as YAML; a round trip restores the same object.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.model.versioned import check_kind, header
from mocap_calib.core.policy import GRAVITY
from mocap_calib.core.result.state import CalibrationTrace, ModelState
from mocap_calib.core.stages.figures import ResidualSeries, StageStats
from mocap_calib.errors import InputError

if TYPE_CHECKING:
    from mocap_calib.core.prepare.session import PreparedSession

Array = NDArray[np.float64]

RESULT_VERSION = 1
KIND = "calibration"
#: Keys that identify a calibration file written before files had a ``kind``.
LEGACY_KEYS = ("gyro_bias", "accel_bias", "T_marker_imu", "gravity_in_mocap")


def _list(a: Array | None) -> list[float] | None:
    return None if a is None else [float(x) for x in np.asarray(a).ravel()]


def _arr(x: Any, n: int | None = None, name: str = "value") -> Array | None:
    """A float vector of ``n`` numbers (or None); ValueError names the key otherwise."""
    if x is None:
        return None
    a = np.asarray(x, dtype=float)
    if n is not None and a.shape != (n,):
        raise ValueError(f"'{name}' must be a list of {n} numbers, got {x!r}")
    return a


@dataclass
class Diagnostics:
    """What the core exposes for inspection (viz, diagnose): never serialised to YAML."""

    residuals: dict[str, ResidualSeries] = field(default_factory=dict)
    iterations: list[dict[str, Any]] = field(default_factory=list)
    trace: CalibrationTrace | None = None
    #: With several takes, each take's own residuals and trace in input order (the first is
    #: the fields above); empty with one take.
    takes: list[Diagnostics] = field(default_factory=list)


@dataclass
class CalibrationResult:
    """A calibration, with 1-sigma uncertainties and the figures behind it.

    ``None`` marks a parameter the session could not determine (see ``unobservable``).
    """

    gyro_bias: Array | None
    accel_bias: Array | None
    rotation_wxyz: Array | None  # R_MI
    translation: Array | None  # p_MI (m)
    gravity_in_mocap: Array | None  # unit vector along g_W
    time_offset: float | None
    sigma_gyro_bias: Array | None = None
    sigma_accel_bias: Array | None = None
    sigma_rotation: Array | None = None
    sigma_translation: Array | None = None
    sigma_gravity: Array | None = None
    sigma_time_offset: float | None = None
    gravity_magnitude: float = GRAVITY
    model: str = "base+time_offset"
    effects: dict[str, dict[str, Any]] = field(default_factory=dict)
    unobservable: dict[str, str] = field(default_factory=dict)
    stages: list[StageStats] = field(default_factory=list)
    solver: dict[str, Any] = field(default_factory=dict)
    noise: NoiseModel = field(default_factory=NoiseModel)
    notes: list[str] = field(default_factory=list)
    session: dict[str, Any] = field(default_factory=dict)
    imu_gaps: dict[str, Any] = field(default_factory=dict)  # what the IMU's gaps were, and done
    takes: list[dict[str, Any]] = field(default_factory=list)  # several takes: each one's own
    clock: dict[str, Any] = field(default_factory=dict)  # the clock search and its verdict
    consistency: dict[str, Any] = field(default_factory=dict)  # independent segments
    sensitivity: dict[str, Any] = field(default_factory=dict)  # under scaled noise densities
    plausibility: dict[str, Any] = field(default_factory=dict)  # the physical checks
    uncertainty: dict[str, Any] = field(default_factory=dict)  # every sigma's terms
    effect_tests: dict[str, Any] = field(default_factory=dict)  # the effects the data show
    model_selection: dict[str, Any] = field(default_factory=dict)  # --model auto: why
    version: int = RESULT_VERSION
    diagnostics: Diagnostics | None = field(default=None, repr=False, compare=False)

    @property
    def R_marker_imu(self) -> Array | None:
        from mocap_calib.core.model import so3

        return None if self.rotation_wxyz is None else so3.quat_to_rotmat(self.rotation_wxyz)

    def model_state(self, s: PreparedSession) -> ModelState:
        """The model state a result file describes (constant biases), for a session prepared again.

        Raises:
            InputError: the result lacks a value the state needs (an unobservable parameter).
        """
        need = {"gyro_bias": self.gyro_bias, "accel_bias": self.accel_bias,
                "T_marker_imu": self.rotation_wxyz, "translation": self.translation,
                "gravity_in_mocap": self.gravity_in_mocap, "time_offset": self.time_offset}
        missing = [k for k, v in need.items() if v is None]
        if missing:
            raise InputError(f"the result has no value for {', '.join(missing)}; a recording "
                             "without the solver's diagnostics needs the full calibration")
        model = Model.parse(self.model)
        effects: dict[str, Array] = {}
        for eff in model.units:
            if eff.in_effects:
                value = (self.effects.get(eff.name) or {}).get(eff.param)
                effects[eff.name] = eff.zero() if value is None else eff.theta_from_report(value)
        g_dir = np.asarray(self.gravity_in_mocap, dtype=float)
        return ModelState(
            R_MI=so3.quat_to_rotmat(np.asarray(self.rotation_wxyz, dtype=float)),
            p_MI=np.asarray(self.translation, dtype=float),
            g_W=self.gravity_magnitude * g_dir / np.linalg.norm(g_dir),
            delta=s.clock_shift + float(self.time_offset or 0.0), model=model, effects=effects,
            bias_t=np.array([s.tau[0]]), bias=np.r_[self.gyro_bias, self.accel_bias][None],
            t_mid=0.5 * float(s.u[0] + s.u[-1]))

    def to_dict(self) -> dict[str, Any]:
        """Plain data: ``kind`` and ``version``, then the keys of ``docs/conventions.md``."""
        return {
            **header(KIND, self.version),
            "gyro_bias": _list(self.gyro_bias),
            "accel_bias": _list(self.accel_bias),
            "T_marker_imu": {
                "rotation_wxyz": _list(self.rotation_wxyz),
                "translation": _list(self.translation),
            },
            "gravity_in_mocap": _list(self.gravity_in_mocap),
            "time_offset": None if self.time_offset is None else float(self.time_offset),
            "sigma": {
                "gyro_bias": _list(self.sigma_gyro_bias),
                "accel_bias": _list(self.sigma_accel_bias),
                "rotation": _list(self.sigma_rotation),
                "translation": _list(self.sigma_translation),
                "gravity_in_mocap": _list(self.sigma_gravity),
                "time_offset": (None if self.sigma_time_offset is None
                                else float(self.sigma_time_offset)),
            },
            "gravity_magnitude": float(self.gravity_magnitude),
            "model": self.model,
            "effects": self.effects,
            "unobservable": dict(self.unobservable),
            "stages": [s.to_dict() for s in self.stages],
            "solver": self.solver,
            "noise": self.noise.to_dict(),
            "session": self.session,
            "imu_gaps": self.imu_gaps,
            **({"takes": self.takes} if self.takes else {}),
            "clock": self.clock,
            "consistency": self.consistency,
            "sensitivity": self.sensitivity,
            "plausibility": self.plausibility,
            "uncertainty": self.uncertainty,
            "effect_tests": self.effect_tests,
            **({"model_selection": self.model_selection} if self.model_selection else {}),
            "notes": list(self.notes),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CalibrationResult:
        """Inverse of :meth:`to_dict`; raises ``KeyError``/``ValueError`` on a malformed dict
        (:class:`~mocap_calib.core.model.versioned.KindError` for another kind of file or a newer
        version)."""
        if "kind" not in d and any(k in d for k in LEGACY_KEYS):
            missing = [k for k in LEGACY_KEYS if k not in d]
            if missing:
                raise KeyError(f"missing key '{missing[0]}'; is this a mocap-calib result file?")
        version = check_kind(d, KIND, RESULT_VERSION, legacy=LEGACY_KEYS)
        for k in LEGACY_KEYS:
            if k not in d:
                raise KeyError(f"missing key '{k}'")
        T = d.get("T_marker_imu") or {}
        sig = d.get("sigma") or {}
        for key, val in (("T_marker_imu", T), ("sigma", sig)):
            if not isinstance(val, dict):
                raise ValueError(f"'{key}' must be a mapping of keys to values")
        to = d.get("time_offset")
        sto = sig.get("time_offset")
        return cls(
            gyro_bias=_arr(d.get("gyro_bias"), 3, "gyro_bias"),
            accel_bias=_arr(d.get("accel_bias"), 3, "accel_bias"),
            rotation_wxyz=_arr(T.get("rotation_wxyz"), 4, "rotation_wxyz"),
            translation=_arr(T.get("translation"), 3, "translation"),
            gravity_in_mocap=_arr(d.get("gravity_in_mocap"), 3, "gravity_in_mocap"),
            time_offset=None if to is None else float(to),
            sigma_gyro_bias=_arr(sig.get("gyro_bias"), 3, "sigma.gyro_bias"),
            sigma_accel_bias=_arr(sig.get("accel_bias"), 3, "sigma.accel_bias"),
            sigma_rotation=_arr(sig.get("rotation"), 3, "sigma.rotation"),
            sigma_translation=_arr(sig.get("translation"), 3, "sigma.translation"),
            sigma_gravity=_arr(sig.get("gravity_in_mocap"), 2, "sigma.gravity_in_mocap"),
            sigma_time_offset=None if sto is None else float(sto),
            gravity_magnitude=float(d.get("gravity_magnitude", GRAVITY)),
            model=(d["model"] if isinstance(d.get("model"), str)
                   else "+".join(d.get("model") or ["base"])),
            effects=dict(d.get("effects") or {}),
            unobservable=dict(d.get("unobservable") or {}),
            stages=[StageStats.from_dict(s) for s in d.get("stages") or []],
            solver=dict(d.get("solver") or {}),
            noise=NoiseModel.from_dict(d.get("noise") or {}),
            notes=list(d.get("notes") or []),
            session=dict(d.get("session") or {}),
            imu_gaps=dict(d.get("imu_gaps") or {}),
            takes=list(d.get("takes") or []),
            clock=dict(d.get("clock") or {}),
            consistency=dict(d.get("consistency") or {}),
            sensitivity=dict(d.get("sensitivity") or {}),
            plausibility=dict(d.get("plausibility") or {}),
            uncertainty=dict(d.get("uncertainty") or {}),
            effect_tests=dict(d.get("effect_tests") or {}),
            model_selection=dict(d.get("model_selection") or {}),
            version=version,
        )
