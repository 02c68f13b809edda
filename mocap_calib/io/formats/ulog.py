"""PX4 ULog files (``.ulg``), read with ``pyulog``.

IMU (``--imu-topic``; see :mod:`~mocap_calib.io.formats.ulog_file` for ``TOPIC:N``):

- ``sensor_combined`` (the default when logged): the IMU PX4 selected (``sensor_selection``),
  as PX4 corrects it with its own calibration, in PX4's body frame FRD (x forward, y right,
  z down): ``gyro_rad`` at ``timestamp`` (us, the autopilot's clock) and
  ``accelerometer_m_s2`` at ``timestamp + accelerometer_timestamp_relative``. A log in which
  PX4 switched to another IMU mid-flight is refused (the stream would mix two sensors).
- ``sensor_gyro:N`` / ``sensor_accel:N``: one IMU as its driver published it (``x, y, z``),
  stamped with ``timestamp_sample`` (when the sensor sampled) where logged. Naming either
  topic reads that IMU: the gyro and accelerometer instances of the same device
  (``device_id``: recent PX4 gives both halves of a chip one id) are paired, else those of the
  same instance number (with a note: older PX4 versions, separate chips).
  Without ``--imu-topic`` and without ``sensor_combined`` the only instance is read; with
  several, one line lists them.
- Accelerometer stamps equal to the gyro's are taken as they are; otherwise the accelerometer
  is interpolated linearly onto the gyro stamps, and gyro samples with no accelerometer sample
  on either side within the gap rule's step are left out (never extrapolated), with a note.

Gaps are not refused here (the calibration handles them, :mod:`mocap_calib.core.policy`):
the notes say how many gaps the stamps show and what the logger's own dropout records say.

Mocap: ``vehicle_mocap_odometry`` (or ``vehicle_visual_odometry``): ``position`` and ``q``
(FRD body to the local NED frame, or to an FRD world), stamped with ``timestamp_sample``,
the time of the measurement on the autopilot's clock. Older logs' ``x, y, z`` fields work too.

Frames: the world is turned from z-down (NED, or FRD) to z-up, as mavros does (x and y swapped,
z negated: NED becomes ENU), so gravity points along -z like in every other input. The body
frames are kept as PX4 logs them: the IMU frame ``I`` is PX4's FRD body frame and the marker
frame ``M`` is the FRD body frame the odometry reports, so ``T_MI`` and the ``px4`` export stay
in PX4's frames.

``pyulog`` stops quietly where a file is cut; :func:`~ulog_file.check_complete` walks the
message headers first and refuses a file that ends inside a message (a truncated copy).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mocap_calib.core.model import so3
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.errors import input_error
from mocap_calib.io.formats.ulog_file import (
    Instance,
    dropout_note,
    instances,
    is_ulog,
    logged_topics,
    open_ulog,
    parse_spec,
    pick_instance,
    stamps_us,
    vector,
)
from mocap_calib.io.merge import merge_on_gyro
from mocap_calib.io.reading import Format, ReadOptions
from mocap_calib.io.streams import Crop, ImuTable, PoseTable
from mocap_calib.io.validate import Lines

IMU_TOPICS = ("sensor_combined", "sensor_gyro", "sensor_accel")
MOCAP_TOPICS = ("vehicle_mocap_odometry", "vehicle_visual_odometry")
#: ``accelerometer_timestamp_relative`` value meaning "no accel sample in this message".
_RELATIVE_INVALID = 0x7FFFFFFF
#: z-down world (NED, FRD) -> z-up world (ENU): swap x and y, negate z. A proper rotation.
R_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_OPT = "--imu-topic"
_XYZ = ("x", "y", "z")


def read_ulog_imu(path: Path | str, topic: str | None, notes: list[str]) -> ImuSamples:
    """The checked IMU samples of a ULog (:func:`ulog_imu_table`)."""
    table = ulog_imu_table(Path(path), topic, notes)
    imu = table.validate()
    notes.extend(table.notes(imu))
    return imu


def ulog_imu_table(path: Path, topic: str | None, notes: list[str], crop: Crop | None = None
                   ) -> ImuTable:
    """IMU samples of ``sensor_combined`` or of one ``sensor_gyro``/``sensor_accel`` pair
    (an IMU switch of ``sensor_combined`` is refused only inside ``crop``)."""
    ulog = open_ulog(path, [*IMU_TOPICS, "sensor_selection"], notes)
    chosen = _choose_imu(ulog, path, topic, notes)
    if chosen[0].name == "sensor_combined":
        label = f"{path} [sensor_combined]"
        us, gyro, accel = _combined(chosen[0].data, label, notes)
        _refuse_switch(ulog, int(us[0]), label, crop)
    else:
        g, a = chosen
        label = f"{path} [{g.spec}, {a.spec}]"
        us, gyro, accel = _raw_pair(g, a, label, notes)
    drop = dropout_note(ulog, int(us[0]), str(path))
    return ImuTable(us * 1000, gyro, accel, Lines(label), note_gaps=True,
                    last_notes=() if drop is None else (drop,))


def _choose_imu(ulog: Any, path: Path, topic: str | None, notes: list[str]) -> list[Instance]:
    """``[sensor_combined]`` or ``[gyro, accel]`` instances to read."""
    src = str(path)
    found = {n: instances(ulog, n) for n in IMU_TOPICS}
    gyros, accels = found["sensor_gyro"], found["sensor_accel"]
    if topic is None:
        if found["sensor_combined"]:
            also = (f"; the log also holds {', '.join(i.spec for i in gyros)} ({_OPT} "
                    "sensor_gyro:N reads one IMU as its driver published it)" if gyros else "")
            notes.append(f"{src}: IMU from sensor_combined, the IMU PX4 selected, as PX4 "
                         f"corrects it with its own calibration{also}")
            return [found["sensor_combined"][0]]
        if gyros and accels:
            g = pick_instance(gyros, "sensor_gyro", None, _OPT, src)
            return [g, _partner(g, accels, src, notes)]
        raise input_error(f"no IMU data in the log: neither sensor_combined nor sensor_gyro with "
                          f"sensor_accel (logged topics read: {logged_topics(ulog)})",
                          "log sensor_combined (PX4's default profile) or sensor_gyro and "
                          "sensor_accel (SDLOG_PROFILE), or pass the file that holds them", src)
    name, wanted = parse_spec(topic)
    if name not in IMU_TOPICS:
        present = [i.spec for n in IMU_TOPICS for i in found[n]]
        raise input_error(f"'{topic}' is not an IMU topic of a PX4 log (IMU topics: "
                          "sensor_combined, sensor_gyro:N, sensor_accel:N)",
                          f"pass {_OPT} with one of: {', '.join(present) or 'none logged'}", src)
    if not found[name]:
        raise input_error(f"no {name} data in the log (logged topics read: "
                          f"{logged_topics(ulog)})", f"pass {_OPT} with a logged IMU topic, or "
                          f"log {name} on the vehicle (SDLOG_PROFILE)", src)
    chosen = pick_instance(found[name], name, wanted, _OPT, src)
    if name == "sensor_combined":
        return [chosen]
    if name == "sensor_gyro":
        return [chosen, _partner(chosen, accels, src, notes)]
    return [_partner(chosen, gyros, src, notes), chosen]


def _partner(inst: Instance, others: list[Instance], src: str, notes: list[str]) -> Instance:
    """The instance of the other raw IMU topic from the same device as ``inst``."""
    other = "sensor_accel" if inst.name == "sensor_gyro" else "sensor_gyro"
    if not others:
        raise input_error(f"{inst.spec} is logged but {other} is not", f"log both sensor_gyro "
                          f"and sensor_accel, or pass {_OPT} sensor_combined", src)
    dev = inst.device_id
    same = [o for o in others if dev is not None and o.device_id == dev]
    if same:
        return same[0]
    by_number = [o for o in others if o.multi_id == inst.multi_id]
    if not by_number:
        raise input_error(f"no {other} instance from the device of {inst.describe()} "
                          f"({other}: {', '.join(o.describe() for o in others)})",
                          f"pass {_OPT} with an IMU logged in both sensor_gyro and "
                          "sensor_accel", src)
    why = "no device ids logged" if dev is None else f"no {other} has device 0x{dev:06X}"
    notes.append(f"{src}: {inst.spec} paired with {by_number[0].spec} by instance number "
                 f"({why}: separate gyro and accelerometer chips?)")
    return by_number[0]


def _combined(data: dict[str, np.ndarray], label: str, notes: list[str]
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    us = data["timestamp"].astype(np.int64)
    gyro = vector(data, "gyro_rad", 3)
    accel = vector(data, "accelerometer_m_s2", 3)
    if gyro is None or accel is None:
        raise input_error("sensor_combined has no gyro_rad/accelerometer_m_s2 fields",
                          "pass a log of a PX4 version that logs them", label)
    rel = data.get("accelerometer_timestamp_relative")
    if rel is None or not np.any(rel != 0):
        return us, gyro, accel
    ok = rel != _RELATIVE_INVALID
    if ok.sum() < 2:
        raise input_error("sensor_combined holds fewer than two accelerometer samples",
                          "pass a log whose sensor_combined is intact", label)
    return _pair(us, gyro, us[ok] + rel[ok].astype(np.int64), accel[ok], label, notes)


def _raw_pair(g: Instance, a: Instance, label: str, notes: list[str]
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    tg, field_g = stamps_us(g.data)
    ta, field_a = stamps_us(a.data)
    gyro, accel = vector(g.data, "xyz", 3, _XYZ), vector(a.data, "xyz", 3, _XYZ)
    if gyro is None or accel is None:
        raise input_error(f"{g.name}/{a.name} have no x, y, z fields", "pass a log of a PX4 "
                          "version that logs them", label)
    if field_g != "timestamp_sample" or field_a != "timestamp_sample":
        notes.append(f"{label}: no timestamp_sample logged; stamped with the publication "
                     "time (timestamp)")
    return _pair(tg, gyro, ta, accel, label, notes)


def _pair(tg: np.ndarray, gyro: np.ndarray, ta: np.ndarray, accel: np.ndarray, label: str,
          notes: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gyro and accelerometer samples on the gyro's stamps (integer us): the shared merge
    step, :func:`~mocap_calib.io.merge.merge_on_gyro`."""
    return merge_on_gyro(tg, gyro, ta, accel, label=label, notes=notes, ns_per_unit=1000)


def _refuse_switch(ulog: Any, origin_us: int, label: str, crop: Crop | None) -> None:
    """Refuse a ``sensor_combined`` in which PX4 switched to another IMU during the log (or
    the part of it ``crop`` keeps)."""
    lo, hi = crop.bounds() if crop is not None and crop.given else (-np.inf, np.inf)
    for sel in instances(ulog, "sensor_selection"):
        for kind in ("gyro", "accel"):
            ids = sel.data.get(f"{kind}_device_id")
            if ids is None or len(ids) < 2 or np.all(ids == ids[0]):
                continue
            t = (sel.data["timestamp"].astype(np.int64) - origin_us) * 1e-6
            before = np.flatnonzero(t <= lo)  # the selection in force at the crop's start on
            inside = np.arange(before[-1] if len(before) else 0, len(t))
            inside = inside[t[inside] <= hi]
            if len(inside) < 2 or np.all(ids[inside] == ids[inside[0]]):
                continue
            first = ids[inside[0]]
            k = int(inside[np.flatnonzero(ids[inside] != first)[0]])
            at = float(t[k])
            raise input_error(f"PX4 switched its {kind} from device 0x{int(first):06X} to "
                              f"0x{int(ids[k]):06X} at {at:.3f} s from the IMU start "
                              "(sensor_selection): sensor_combined mixes two IMUs",
                              f"pass {_OPT} sensor_gyro:N to read one IMU, or --end "
                              f"{max(at, 0.0):.1f} to calibrate the part before the switch",
                              label)


def _mocap_instance(ulog: Any, path: Path, topic: str | None, notes: list[str]) -> Instance:
    src = str(path)
    names = ", ".join(MOCAP_TOPICS)
    if topic is not None:
        name, wanted = parse_spec(topic)
        if name not in MOCAP_TOPICS:
            raise input_error(f"'{topic}' is not a mocap topic of a PX4 log",
                              f"pass --mocap-topic with one of: {names}", src)
        candidates = [name]
    else:
        wanted, candidates = None, list(MOCAP_TOPICS)
    for name in candidates:
        found = instances(ulog, name)
        if found:
            if topic is None and name != MOCAP_TOPICS[0]:
                notes.append(f"{src}: no {MOCAP_TOPICS[0]} in the log; using {name}")
            return pick_instance(found, name, wanted, "--mocap-topic", src)
    shown = names if topic is None else candidates[0]
    read = logged_topics(ulog)  # the reader asks the log for the mocap topics only
    raise input_error(f"no {shown} data in the log"
                      + ("" if read == "none" else f" (logged topics read: {read})"),
                      f"log the mocap topic ({names}) on the vehicle (SDLOG_PROFILE), or pass "
                      "the file that holds it", src)


def read_ulog_mocap(path: Path | str, topic: str | None, notes: list[str]) -> MocapPoses:
    """The checked marker poses of a ULog (:func:`ulog_pose_table`)."""
    return ulog_pose_table(Path(path), topic, notes).validate()


def ulog_pose_table(path: Path, topic: str | None, notes: list[str]) -> PoseTable:
    """Marker poses of the mocap (or visual) odometry topic, turned into a z-up world."""
    ulog = open_ulog(path, list(MOCAP_TOPICS), notes)
    inst = _mocap_instance(ulog, path, topic, notes)
    name, data = inst.name, inst.data
    label = f"{path} [{name if inst.multi_id == 0 else inst.spec}]"
    us, _ = stamps_us(data)
    p = vector(data, "position", 3, ("x", "y", "z"))
    q = vector(data, "q", 4)
    if p is None or q is None:
        raise input_error(f"{name} has no position/q fields", "pass a log of a PX4 version "
                          "that logs the odometry pose", label)
    frames = data.get("pose_frame")
    if frames is not None and np.any((frames != 1) & (frames != 2)):
        notes.append(f"{label}: pose_frame is not NED or FRD for some samples; read as z-down")
    keep_nan = ~np.isfinite(q).all(axis=1) | ~np.isfinite(p).all(axis=1)
    q_ok = np.where(keep_nan[:, None], np.array([1.0, 0.0, 0.0, 0.0]), q)
    n = np.linalg.norm(q_ok, axis=1, keepdims=True)
    R = R_ENU_NED @ so3.quat_to_rotmat(q_ok / np.where(n > 0, n, 1.0))
    q_enu = so3.rotmat_to_quat(R)
    q_enu[keep_nan] = np.nan
    p_enu = p @ R_ENU_NED.T
    notes.append(f"{label}: PX4 z-down world turned into a z-up world (x<->y, z negated); "
                 "the body frames stay FRD")
    return PoseTable(us * 1000, q_enu, p_enu, Lines(label))


def _imu(path: Path, opts: ReadOptions, notes: list[str]) -> ImuTable:
    return ulog_imu_table(path, opts.recording.imu_topic, notes, opts.crop)


def _poses(path: Path, opts: ReadOptions, notes: list[str]) -> PoseTable:
    return ulog_pose_table(path, opts.recording.mocap_topic, notes)


FORMAT = Format("ulog", "PX4 ULog", lambda p: not p.is_dir() and is_ulog(p), _imu, _poses,
                options=frozenset({"imu_topic", "mocap_topic"}))
