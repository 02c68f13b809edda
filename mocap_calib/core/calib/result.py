"""Typed results: the calibration (``docs/conventions.md`` keys), stage figures, residual series.

:meth:`CalibrationResult.to_dict` / :meth:`CalibrationResult.from_dict` give the versioned
plain-data form that ``io`` writes as YAML; a round trip restores the same object.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.model.versioned import check_kind, header

if TYPE_CHECKING:
    from mocap_calib.core.calib.state import CalibrationTrace

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
class StageStats:
    """Figures of one stage.

    Attributes:
        name: ``attitude``, ``velocity`` or ``position``.
        unit: unit of the residuals (per axis).
        rms_before, rms_after: residual RMS per axis before / after the stage's solve (all
            residuals, as in the residual series).
        rms_after_inliers: the same without the residuals the robust kernel down-weighted.
        rms_rotation_deg: for the position stage, the attitude part of the residuals.
        n_factors: number of factors (intervals or windows).
        n_residuals: number of residual vectors (intervals or mocap samples).
        outliers: residuals down-weighted by the robust kernel (weight < 0.5).
        iterations: LM iterations; seconds: wall time of the stage.
        chi2_per_dof: whitened cost per degree of freedom at the solution (1 = noise as modelled).
    """

    name: str
    unit: str
    rms_before: list[float]
    rms_after: list[float]
    n_factors: int
    n_residuals: int
    outliers: int
    iterations: int
    seconds: float
    chi2_per_dof: float
    rms_rotation_deg: list[float] | None = None
    rms_after_inliers: list[float] | None = None
    batch_evaluations: int = 0

    def to_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in self.__dict__.items() if v is not None}
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StageStats:
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})


@dataclass
class ResidualSeries:
    """Residuals of one stage over time, for inspection (not written to YAML).

    Attributes:
        t: (n,) mocap-clock times (s since the mocap origin).
        before, after: (n, 3) residuals before / after the solve, in ``unit``.
        weight: (n,) robust weights at the solution (1 = inlier).
        unit: unit of the residuals.
        rotation_before, rotation_after: (n, 3) attitude residuals (deg) of the position stage.
    """

    t: Array
    before: Array
    after: Array
    weight: Array
    unit: str
    rotation_before: Array | None = None
    rotation_after: Array | None = None


@dataclass
class Diagnostics:
    """What the core exposes for inspection (viz, diagnose): never serialised to YAML."""

    residuals: dict[str, ResidualSeries] = field(default_factory=dict)
    iterations: list[dict[str, Any]] = field(default_factory=list)
    trace: CalibrationTrace | None = None


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
    gravity_magnitude: float = 9.81
    model: str = "base+time_offset"
    effects: dict[str, dict[str, Any]] = field(default_factory=dict)
    unobservable: dict[str, str] = field(default_factory=dict)
    stages: list[StageStats] = field(default_factory=list)
    solver: dict[str, Any] = field(default_factory=dict)
    noise: NoiseModel = field(default_factory=NoiseModel)
    notes: list[str] = field(default_factory=list)
    session: dict[str, Any] = field(default_factory=dict)
    clock: dict[str, Any] = field(default_factory=dict)  # the clock search and its verdict
    consistency: dict[str, Any] = field(default_factory=dict)  # independent segments
    sensitivity: dict[str, Any] = field(default_factory=dict)  # under scaled noise densities
    plausibility: dict[str, Any] = field(default_factory=dict)  # the physical checks
    version: int = RESULT_VERSION
    diagnostics: Diagnostics | None = field(default=None, repr=False, compare=False)

    @property
    def R_marker_imu(self) -> Array | None:
        from mocap_calib.core.model import so3

        return None if self.rotation_wxyz is None else so3.quat_to_rotmat(self.rotation_wxyz)

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
            "clock": self.clock,
            "consistency": self.consistency,
            "sensitivity": self.sensitivity,
            "plausibility": self.plausibility,
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
            gravity_magnitude=float(d.get("gravity_magnitude", 9.81)),
            model=(d["model"] if isinstance(d.get("model"), str)
                   else "+".join(d.get("model") or ["base"])),
            effects=dict(d.get("effects") or {}),
            unobservable=dict(d.get("unobservable") or {}),
            stages=[StageStats.from_dict(s) for s in d.get("stages") or []],
            solver=dict(d.get("solver") or {}),
            noise=NoiseModel.from_dict(d.get("noise") or {}),
            notes=list(d.get("notes") or []),
            session=dict(d.get("session") or {}),
            clock=dict(d.get("clock") or {}),
            consistency=dict(d.get("consistency") or {}),
            sensitivity=dict(d.get("sensitivity") or {}),
            plausibility=dict(d.get("plausibility") or {}),
            version=version,
        )
