"""One writer per target tool; frames and time-offset signs as in ``docs/exports.md``.

Ours: ``T_MI`` (IMU pose in the marker frame), ``t_d`` (an IMU sample stamped ``t`` was measured
at mocap time ``t + t_d``), ``g_W`` (gravity in the mocap world). Most tools write a clock shift
``t_imu = t_other + shift``, which is ``-t_d`` with the mocap as the other sensor.

- ``kalibr``: Kalibr's IMU yaml (``imu.yaml`` keys; the result form with ``model``, ``T_i_b``,
  ``time_offset`` and, for scale/misalignment models, ``accelerometers.M`` and
  ``gyroscopes.M/A/C_gyro_i``). Kalibr's IMU ``time_offset`` maps the IMU's stamps onto the
  reference clock (``t_ref = t_imu + time_offset``); the reference here is the mocap: ``t_d``.
- ``openvins``: ``kalibr_imu_chain.yaml`` (OpenCV ``%YAML:1.0``, ``imu0`` node) with the five
  intrinsic matrices of OpenVINS's ``kalibr`` model (see :mod:`.intrinsics`).
- ``vins``: VINS-Mono/Fusion keys; ``td`` follows VINS's "read image clock + td = IMU clock",
  with the mocap as the image stream: ``-t_d``.
- ``orbslam3``: ``IMU.*`` noise keys and ``IMU.Frequency`` (no clock offset parameter).
- ``basalt``: ``mocap_calibration.json``: ``T_imu_marker`` (``T_IM``), ``T_mocap_world`` (the
  mocap frame from a gravity-aligned world, ``T_WG``), ``mocap_time_offset_ns`` (Basalt adds it
  to mocap stamps to get IMU time: ``-t_d``).
- ``px4``: QGroundControl parameter file with ``EKF2_EV_DELAY`` (EKF2 dates a vision sample
  ``delay`` before its stamp: ``t_d`` in ms) and ``EKF2_EV_POS_X/Y/Z`` (the marker origin in the
  body frame: ``p_IM``; the IMU frame must be PX4's FRD body frame, as it is for a ULog's
  ``sensor_combined``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import EFFECTS
from mocap_calib.core.model.parameters import (
    GRAVITY_DIRECTION,
    ROTATION,
    TIME_OFFSET,
    TRANSLATION,
    Parameter,
)
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.errors import InputError
from mocap_calib.export.intrinsics import ImuIntrinsics, intrinsics_of, kalibr_gyro

TARGETS = ("kalibr", "openvins", "vins", "orbslam3", "basalt", "px4")
#: Default file name per target (what the tool calls it).
FILE_NAMES = {"kalibr": "imu.yaml", "openvins": "kalibr_imu_chain.yaml", "vins": "vins_imu.yaml",
              "orbslam3": "orbslam3_imu.yaml", "basalt": "mocap_calibration.json",
              "px4": "mocap_calib.params"}


@dataclass
class ExportInputs:
    """What an export needs: the calibration, the noise model and the IMU stream's facts."""

    result: CalibrationResult
    noise: NoiseModel
    noise_source: str
    imu_rate_hz: float
    imu_topic: str = "/imu0"
    source: str = "calib.yaml"


@dataclass
class Exported:
    """The file text and one-line notes for the user."""

    target: str
    text: str
    notes: list[str] = field(default_factory=list)


def _f(x: float) -> str:
    """A float that YAML, JSON and OpenCV all read back as the same real (always a '.' or
    an exponent, never an integer)."""
    s = repr(float(x))
    return s if any(c in s for c in ".en") else s + ".0"


def _row(v: Any) -> str:
    return "[" + ", ".join(_f(x) for x in np.ravel(v)) + "]"


def _matrix(name: str, m: np.ndarray, indent: str) -> list[str]:
    return [f"{indent}{name}:"] + [f"{indent}  - {_row(r)}" for r in np.asarray(m)]


def _need(inp: ExportInputs, *params: Parameter) -> None:
    r = inp.result
    for p in params:
        if r.value(p) is None:
            why = r.unobservable.get(p.name, "not determined")
            raise InputError(f"{inp.source}: {p.name} is null ({why}); calibrate a session "
                             f"that determines it before exporting")


def _t_d(inp: ExportInputs) -> float:
    _need(inp, TIME_OFFSET)
    assert inp.result.time_offset is not None
    return float(inp.result.time_offset)


def _T_IM(inp: ExportInputs) -> tuple[np.ndarray, np.ndarray]:
    """``R_IM``, ``p_IM``: the marker frame's pose in the IMU frame (``T_MI^-1``)."""
    _need(inp, ROTATION, TRANSLATION)
    R_MI = ROTATION.state(inp.result.value(ROTATION))
    return R_MI.T, -R_MI.T @ np.asarray(inp.result.value(TRANSLATION))


def _noise_lines(n: NoiseModel, indent: str = "") -> list[str]:
    return [f"{indent}accelerometer_noise_density: {_f(n.accelerometer_noise_density)}"
            "  # m/s^2/sqrt(Hz)",
            f"{indent}accelerometer_random_walk: {_f(n.accelerometer_random_walk)}"
            "  # m/s^3/sqrt(Hz)",
            f"{indent}gyroscope_noise_density: {_f(n.gyroscope_noise_density)}"
            "  # rad/s/sqrt(Hz)",
            f"{indent}gyroscope_random_walk: {_f(n.gyroscope_random_walk)}  # rad/s^2/sqrt(Hz)"]


def _header(inp: ExportInputs, target: str) -> list[str]:
    return [f"# {target} configuration exported by mocap-calib from {inp.source}",
            f"# noise densities: {inp.noise_source}",
            "# frames and time-offset signs: docs/exports.md"]


def _intr(inp: ExportInputs, notes: list[str]) -> ImuIntrinsics:
    return intrinsics_of(inp.result.effects)


def _kalibr(inp: ExportInputs, notes: list[str]) -> str:
    intr = _intr(inp, notes)
    t_d = _t_d(inp)
    lines = [*_header(inp, "Kalibr IMU"),
             f"# clock: Kalibr's IMU time_offset maps IMU stamps onto the reference (mocap) "
             f"clock, t_mocap = t_imu + time_offset; as a camera-style shift t_imu = t_mocap + "
             f"shift it is {_f(-t_d)} s",
             *_noise_lines(inp.noise), f"rostopic: {inp.imu_topic}",
             f"update_rate: {_f(inp.imu_rate_hz)}",
             f"model: {'calibrated' if intr.is_identity else 'scale-misalignment'}",
             *_matrix("T_i_b", np.eye(4), ""), f"time_offset: {_f(t_d)}"]
    if not intr.is_identity:
        kg = kalibr_gyro(intr)
        lines += ["accelerometers:", *_matrix("M", intr.accel_matrix, "  "), "gyroscopes:",
                  *_matrix("M", kg.M, "  "), *_matrix("A", kg.A, "  "),
                  *_matrix("C_gyro_i", kg.C_gyro_i, "  ")]
    return "\n".join(lines) + "\n"


def _openvins(inp: ExportInputs, notes: list[str]) -> str:
    intr = _intr(inp, notes)
    kg = kalibr_gyro(intr)
    t_d = _t_d(inp)
    lines = ["%YAML:1.0", "", *_header(inp, "OpenVINS kalibr_imu_chain.yaml"),
             f"# OpenVINS reads the noise and the five matrices; time_offset is Kalibr's "
             f"(t_mocap = t_imu + time_offset), the camera-style shift is {_f(-t_d)} s",
             f"# gravity_mag for estimator_config.yaml: {_f(inp.result.gravity_magnitude)}",
             "imu0:", *_matrix("T_i_b", np.eye(4), "  "), *_noise_lines(inp.noise, "  "),
             f"  rostopic: {inp.imu_topic}", f"  time_offset: {_f(t_d)}",
             f"  update_rate: {_f(inp.imu_rate_hz)}", '  model: "kalibr"',
             *_matrix("Tw", kg.M, "  "), *_matrix("R_IMUtoGYRO", kg.C_gyro_i, "  "),
             *_matrix("Ta", intr.accel_matrix, "  "), *_matrix("R_IMUtoACC", np.eye(3), "  "),
             *_matrix("Tg", intr.g_sensitivity, "  ")]
    return "\n".join(lines) + "\n"


def _vins(inp: ExportInputs, notes: list[str]) -> str:
    n = inp.noise
    t_d = _t_d(inp)
    lines = ["%YAML:1.0", *_header(inp, "VINS-Mono/VINS-Fusion IMU"),
             "# continuous-time densities; VINS users often inflate them several times",
             f"imu_topic: \"{inp.imu_topic}\"",
             f"acc_n: {_f(n.accelerometer_noise_density)}",
             f"gyr_n: {_f(n.gyroscope_noise_density)}",
             f"acc_w: {_f(n.accelerometer_random_walk)}",
             f"gyr_w: {_f(n.gyroscope_random_walk)}",
             f"g_norm: {_f(inp.result.gravity_magnitude)}",
             "# td: read image clock + td = IMU clock, with the mocap as the image stream; it is",
             "# the camera's offset only if the camera shares the mocap's clock",
             "estimate_td: 1", f"td: {_f(-t_d)}"]
    return "\n".join(lines) + "\n"


def _orbslam3(inp: ExportInputs, notes: list[str]) -> str:
    n = inp.noise
    t_d = _t_d(inp)
    notes.append("ORB-SLAM3 has no clock-offset parameter: the offset is in a comment only")
    lines = ["%YAML:1.0", *_header(inp, "ORB-SLAM3 IMU"),
             f"# mocap clock offset (not an ORB-SLAM3 parameter): t_imu = t_mocap + {_f(-t_d)}",
             f"IMU.NoiseGyro: {_f(n.gyroscope_noise_density)}",
             f"IMU.NoiseAcc: {_f(n.accelerometer_noise_density)}",
             f"IMU.GyroWalk: {_f(n.gyroscope_random_walk)}",
             f"IMU.AccWalk: {_f(n.accelerometer_random_walk)}",
             f"IMU.Frequency: {_f(inp.imu_rate_hz)}"]
    return "\n".join(lines) + "\n"


def _se3(R: np.ndarray, p: np.ndarray) -> dict[str, float]:
    q = so3.rotmat_to_quat(R)
    return {"px": float(p[0]), "py": float(p[1]), "pz": float(p[2]), "qx": float(q[1]),
            "qy": float(q[2]), "qz": float(q[3]), "qw": float(q[0])}


def _basalt(inp: ExportInputs, notes: list[str]) -> str:
    R_IM, p_IM = _T_IM(inp)
    _need(inp, GRAVITY_DIRECTION)
    R_GW = so3.rotation_between(np.asarray(inp.result.value(GRAVITY_DIRECTION)),
                               [0.0, 0.0, -1.0])
    value = {"T_mocap_world": _se3(R_GW.T, np.zeros(3)), "T_imu_marker": _se3(R_IM, p_IM),
             "mocap_time_offset_ns": int(round(-_t_d(inp) * 1e9)), "mocap_to_imu_offset_ns": 0}
    notes.append("Basalt's world is the gravity-aligned frame of 'mocap-calib groundtruth' "
                 "(z up, yaw of the mocap world)")
    return json.dumps({"value0": value}, indent=4, allow_nan=False) + "\n"


def _px4(inp: ExportInputs, notes: list[str]) -> str:
    R_IM, p_IM = _T_IM(inp)
    t_d = _t_d(inp)
    delay_ms = t_d * 1e3
    if delay_ms < 0:
        notes.append(f"the mocap is stamped {-delay_ms:.2f} ms after the IMU samples it matches "
                     "(t_d < 0); EKF2_EV_DELAY cannot be negative and is set to 0")
        delay_ms = 0.0
    tilt = float(so3.angle_deg(R_IM))
    if tilt > 1.0:
        notes.append(f"the mocap body's axes are {tilt:.1f} deg from the IMU's (FRD) axes; PX4 "
                     "has no parameter for that: align the rigid body's axes in the mocap "
                     "software (or rotate the poses in the bridge)")
    notes.append("EKF2_EV_POS assumes the IMU is at the body origin (EKF2_IMU_POS = 0); "
                 "otherwise add EKF2_IMU_POS_X/Y/Z")
    rows = [("EKF2_EV_DELAY", delay_ms), ("EKF2_EV_POS_X", p_IM[0]),
            ("EKF2_EV_POS_Y", p_IM[1]), ("EKF2_EV_POS_Z", p_IM[2])]
    lines = [f"# Onboard parameters exported by mocap-calib from {inp.source}",
             "# EKF2_EV_DELAY [ms]: vision/mocap samples are dated that long before their stamp "
             "(both streams stamped on the autopilot clock, as in a ULog)",
             "# EKF2_EV_POS_* [m]: the mocap body's origin in the FRD body (IMU) frame",
             "#", "# MAV ID\tCOMPONENT ID\tPARAM NAME\tVALUE\t(TYPE)"]
    lines += [f"1\t1\t{name}\t{value:.6f}\t9" for name, value in rows]
    return "\n".join(lines) + "\n"


_WRITERS = {"kalibr": _kalibr, "openvins": _openvins, "vins": _vins, "orbslam3": _orbslam3,
            "basalt": _basalt, "px4": _px4}
#: The kinds of effect (``Effect.acts_on``) each target has parameters for; every other
#: effect of a result is named in a note, never dropped silently. (The clock offset is
#: handled by each writer: ORB-SLAM3's comment says it has none.)
_WRITES: dict[str, frozenset[str]] = {
    "kalibr": frozenset({"clock", "w", "f"}), "openvins": frozenset({"clock", "w", "f", "gravity"}),
    "vins": frozenset({"clock", "gravity"}), "orbslam3": frozenset({"clock"}),
    "basalt": frozenset({"clock"}), "px4": frozenset({"clock"})}


def _not_exported(result: CalibrationResult, target: str) -> list[str]:
    """One note per estimated effect the target has no parameter for."""
    notes = []
    for name, rec in result.effects.items():
        eff = EFFECTS.get(name)
        if eff is None or eff.acts_on in _WRITES[target]:
            continue
        if all(v is None for k, v in rec.items() if k != "sigma"):
            continue  # unobservable: nothing to export
        if eff.acts_on == "time":
            why = "the target estimates biases online"
        elif eff.acts_on in ("w", "f"):
            why = f"{target} has no IMU intrinsics"
        else:
            why = f"{target} has no parameter for it"
        notes.append(f"{name} is not exported ({why})")
    return notes


def _numbers_used(inp: ExportInputs) -> list[tuple[str, Any]]:
    """Every number a writer can take, by its key in the result file (or its option)."""
    r = inp.result
    pairs: list[tuple[str, Any]] = [
        ("T_marker_imu.rotation_wxyz", r.rotation_wxyz), ("T_marker_imu.translation",
                                                          r.translation),
        ("gravity_in_mocap", r.gravity_in_mocap), ("time_offset", r.time_offset),
        ("gravity_magnitude", r.gravity_magnitude), ("the IMU rate", inp.imu_rate_hz)]
    pairs += [(f"noise.{k}", v) for k, v in inp.noise.to_dict().items()]
    for name, rec in r.effects.items():
        eff = EFFECTS.get(name)
        if eff is not None and isinstance(rec, dict):
            pairs.append((f"effects.{name}.{eff.param}", rec.get(eff.param)))
    return [(k, v) for k, v in pairs if v is not None]


def _refuse_non_finite(inp: ExportInputs, target: str) -> None:
    """A NaN or infinite value would be written as ``nan`` (a PX4 parameter), ``NaN`` (invalid
    JSON for Basalt) or ``.nan``: refuse it, and a rotation or gravity direction of no
    length, whose frames would be NaN."""
    for key, value in _numbers_used(inp):
        try:
            a = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            continue  # not a plain array (a mapping): its effect is not exported as numbers
        if not np.all(np.isfinite(a)):
            raise InputError(f"{inp.source}: {key} is {a.tolist()}, not a finite number; "
                             f"nothing exported to {target}: calibrate again")
    for key, value in (("T_marker_imu.rotation_wxyz", inp.result.rotation_wxyz),
                       ("gravity_in_mocap", inp.result.gravity_in_mocap)):
        if value is not None and not np.any(np.asarray(value, dtype=float) != 0):
            raise InputError(f"{inp.source}: {key} is {np.asarray(value).tolist()}, of zero "
                             f"length (no direction); nothing exported to {target}: calibrate "
                             "again")


def export_calibration(inp: ExportInputs, target: str) -> Exported:
    """The file for ``target``.

    Raises:
        InputError: unknown target, a parameter the target needs is null in the result, or a
            number it would write is not finite.
    """
    if target not in _WRITERS:
        raise InputError(f"unknown --to '{target}'; choose one of: {', '.join(TARGETS)}")
    _refuse_non_finite(inp, target)
    notes = _not_exported(inp.result, target)
    text = _WRITERS[target](inp, notes)
    return Exported(target, text, notes)
