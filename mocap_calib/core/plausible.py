"""What a physically possible calibration looks like: the limits an answer must respect.

A calibration can converge to numbers no drone has: an accel bias of 4 m/s^2, a mocap world
tipped by 90 deg, an IMU a metre from its markers, scale errors of 20 %. Such answers come from
a wrong clock, a convention mix-up or an effect the model lacks, never from the IMU, so they are
refused instead of printed. The session-level limits are here; each effect's own limits are
part of its rung of the ladder (:data:`~mocap_calib.core.model.effects.EFFECTS`). All can be
overridden per run (``--plausible FILE``); ``docs/diagnosis.md`` has the table.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.effects import EFFECTS

Array = NDArray[np.float64]

#: Axis-aligned up directions of a mocap world (Vicon and ROS: +z, OptiTrack Motive: +y).
AXES = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0), "+z": (0, 0, 1),
        "-z": (0, 0, -1)}


@dataclass(frozen=True)
class PlausibleLimits:
    """Session-level limits (per axis where a vector) and the effects' own limits.

    Attributes:
        gyro_bias: rad/s; uncalibrated MEMS gyros stay within a few deg/s.
        accel_bias: m/s^2; uncalibrated MEMS accelerometers stay within about 60 mg.
        lever_arm: m between the IMU and the marker body's origin.
        tilt_deg: the mocap world's up axis against gravity (ground planes are levelled).
        mocap_position_sigma_m, mocap_rotation_sigma_deg: the mocap noise the residuals imply;
            beyond these the model does not describe the data (wrong clock or conventions).
        clock_refinement_s: how far the fine clock offset may move from the coarse search.
        effects: per effect, its limits by name (defaults from the ladder).
    """

    gyro_bias: float = 0.2
    accel_bias: float = 1.0
    lever_arm: float = 1.0
    tilt_deg: float = 5.0
    mocap_position_sigma_m: float = 0.02
    mocap_rotation_sigma_deg: float = 3.0
    clock_refinement_s: float = 0.05
    effects: dict[str, dict[str, float]] = field(
        default_factory=lambda: {n: dict(e.limits) for n, e in EFFECTS.items() if e.limits})

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PlausibleLimits:
        """Defaults overridden by ``d`` (unknown keys raise ``KeyError``)."""
        base = cls()
        names = {f.name for f in fields(cls)} - {"effects"}
        top = {}
        for k, v in d.items():
            if k == "effects":
                continue
            if k not in names:
                raise KeyError(k)
            top[k] = float(v)
        effects = {n: dict(lim) for n, lim in base.effects.items()}
        for name, lim in (d.get("effects") or {}).items():
            if name not in effects:
                raise KeyError(f"effects.{name}")
            for k, v in lim.items():
                if k not in effects[name]:
                    raise KeyError(f"effects.{name}.{k}")
                effects[name][k] = float(v)
        return replace(base, **top, effects=effects)


def up_axis(g_dir: Array) -> tuple[str, float]:
    """The mocap world axis closest to "up" (against gravity) and the tilt from it (deg)."""
    up = -np.asarray(g_dir, dtype=float) / np.linalg.norm(g_dir)
    name, ax = max(AXES.items(), key=lambda kv: float(np.dot(kv[1], up)))
    return name, float(np.degrees(np.arccos(np.clip(np.dot(ax, up), -1.0, 1.0))))


def effect_problem(effect: str, value: object, limits: PlausibleLimits) -> str | None:
    """One line when an effect's estimate (in report form) is outside its plausible range."""
    lim = limits.effects.get(effect)
    if not lim or value is None:
        return None
    eff = EFFECTS[effect]
    if eff.acts_on == "size":  # the lever arms' lengths
        th = eff.theta_from_report(value)
        v = np.array([np.linalg.norm(th[0:3]), np.linalg.norm(th[3:6])])
    else:
        v = np.asarray(value, dtype=float)
    if eff.about_identity:  # M = I + E: its diagonal's scale, off-diagonal misalignment
        scale = float(np.abs(np.diag(v) - 1.0).max())
        mis = float(np.degrees(np.abs(v - np.diag(np.diag(v))).max()))
        if scale > lim["scale"] or mis > lim["misalignment_deg"]:
            return (f"{effect}: scale error up to {100 * scale:.1f} %, misalignment up to "
                    f"{mis:.1f} deg (plausible: {100 * lim['scale']:.0f} %, "
                    f"{lim['misalignment_deg']:g} deg)")
        return None
    if "min" in lim:  # an interval for a signed value (|g|)
        bad = float(v.min()) < lim["min"] or float(v.max()) > lim["max"]
        shown, bounds = float(v.max()), f"{lim['min']:g}-{lim['max']:g}"
    else:  # a magnitude
        shown, bounds = float(np.abs(v).max()), f"up to {lim['max']:g}"
        bad = shown > lim["max"]
    if bad:
        return f"{effect}: {shown:.4g} {EFFECTS[effect].unit} (plausible: {bounds})"
    return None
