"""PX4 ULog files (``.ulg``), read with ``pyulog``.

- IMU: ``sensor_combined`` (``gyro_rad``, ``accelerometer_m_s2``, both in PX4's body frame FRD:
  x forward, y right, z down), stamped with ``timestamp`` (us, the autopilot's clock). PX4 logs
  the accelerometer at ``timestamp + accelerometer_timestamp_relative``; when that is not zero
  the accel is interpolated onto the gyro stamps (and a note says so).
- Mocap: ``vehicle_mocap_odometry`` (or ``vehicle_visual_odometry``): ``position`` and ``q``
  (FRD body to the local NED frame, or to an FRD world), stamped with ``timestamp_sample``,
  the time of the measurement on the autopilot's clock. Older logs' ``x, y, z`` fields work too.

Frames: the world is turned from z-down (NED, or FRD) to z-up, as mavros does (x and y swapped,
z negated: NED becomes ENU), so gravity points along -z like in every other input. The body
frames are kept as PX4 logs them: the IMU frame ``I`` is PX4's FRD body frame of
``sensor_combined`` and the marker frame ``M`` is the FRD body frame the odometry reports, so
``T_MI`` and the ``px4`` export stay in PX4's frames.

``pyulog`` stops quietly where a file is cut; this reader walks the message headers first and
refuses a file that ends inside a message (a truncated copy) instead of calibrating part of it.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import numpy as np

from mocap_calib.core.model import so3
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.errors import input_error
from mocap_calib.io.checks import Lines, validate_imu, validate_mocap

ULOG_MAGIC = b"ULog\x01\x12\x35"
IMU_TOPICS = ("sensor_combined",)
MOCAP_TOPICS = ("vehicle_mocap_odometry", "vehicle_visual_odometry")
#: ``accelerometer_timestamp_relative`` value meaning "no accel sample in this message".
_RELATIVE_INVALID = 0x7FFFFFFF
#: z-down world (NED, FRD) -> z-up world (ENU): swap x and y, negate z. A proper rotation.
R_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def is_ulog(path: Path | str) -> bool:
    path = Path(path)
    if not path.is_file():
        return path.suffix == ".ulg"
    with open(path, "rb") as f:
        return f.read(7) == ULOG_MAGIC or path.suffix == ".ulg"


def check_complete(path: Path) -> None:
    """Raise if the file is not a ULog or ends inside a message (a truncated copy)."""
    data = path.read_bytes()
    if len(data) < 16 or data[:7] != ULOG_MAGIC:
        raise input_error("not a PX4 ULog file (no ULog header)",
                          "pass the .ulg file the autopilot wrote", str(path))
    view = memoryview(data)
    pos, n = 16, len(data)
    unpack = struct.Struct("<HB").unpack_from
    while pos + 3 <= n:
        size, _ = unpack(view, pos)
        pos += 3 + size
    if pos != n:
        raise input_error(f"the file ends inside a message (byte {n} of a message that needs "
                          f"{pos}): it is truncated", "copy the complete log from the vehicle "
                          "again", str(path))


def _open(path: Path, names: list[str]) -> Any:
    from pyulog import ULog
    from pyulog.core import ULogException

    if not path.is_file():
        raise input_error("file not found", "check the path", str(path))
    check_complete(path)
    try:
        return ULog(str(path), message_name_filter_list=names)
    except (ULogException, ValueError, struct.error, IndexError, KeyError) as err:
        raise input_error(f"cannot parse the ULog ({' '.join(str(err).split())[:120]})",
                          "copy the complete log from the vehicle again", str(path)) from None


def _topics(ulog: Any) -> dict[str, int]:
    counts: dict[str, int] = {}
    for d in ulog.data_list:
        counts[d.name] = counts.get(d.name, 0) + len(d.data["timestamp"])
    return counts


def _dataset(ulog: Any, path: Path, wanted: str | None, allowed: tuple[str, ...], what: str,
             option: str) -> tuple[str, dict[str, np.ndarray]]:
    present = {d.name for d in ulog.data_list}
    names = ", ".join(allowed)
    if wanted is not None and wanted not in allowed:
        raise input_error(f"'{wanted}' is not a {what} topic of a PX4 log", f"pass {option} "
                          f"with one of: {names}", str(path))
    choices = [wanted] if wanted is not None else [n for n in allowed if n in present]
    if not choices or choices[0] not in present:
        logged = ", ".join(f"{k} ({v})" for k, v in sorted(_topics(ulog).items())) or "none"
        raise input_error(f"no {names if wanted is None else wanted} data in the log (logged "
                          f"topics read: {logged})", f"log the {what} topic ({names}) on the "
                          "vehicle (SDLOG_PROFILE), or pass the file that holds it", str(path))
    name = choices[0]
    return name, ulog.get_dataset(name, 0).data


def _vector(data: dict[str, np.ndarray], base: str, n: int, alt: tuple[str, ...] = ()
            ) -> np.ndarray | None:
    keys = [f"{base}[{i}]" for i in range(n)]
    if all(k in data for k in keys):
        return np.stack([data[k].astype(np.float64) for k in keys], axis=1)
    if alt and all(k in data for k in alt):
        return np.stack([data[k].astype(np.float64) for k in alt], axis=1)
    return None


def read_ulog_imu(path: Path | str, topic: str | None, notes: list[str]) -> ImuSamples:
    """IMU samples of ``sensor_combined`` (FRD body frame, autopilot clock)."""
    path = Path(path)
    ulog = _open(path, list(IMU_TOPICS))
    name, data = _dataset(ulog, path, topic, IMU_TOPICS, "IMU", "--imu-topic")
    label = f"{path} [{name}]"
    ns = data["timestamp"].astype(np.int64) * 1000
    gyro = _vector(data, "gyro_rad", 3)
    accel = _vector(data, "accelerometer_m_s2", 3)
    if gyro is None or accel is None:
        raise input_error(f"{name} has no gyro_rad/accelerometer_m_s2 fields",
                          "pass a log of a PX4 version that logs them", label)
    rel = data.get("accelerometer_timestamp_relative")
    if rel is not None and np.any(rel != 0):
        ok = rel != _RELATIVE_INVALID
        t_acc = ns[ok] + rel[ok].astype(np.int64) * 1000
        if ok.sum() < 2 or np.any(np.diff(t_acc) <= 0):
            raise input_error("the accelerometer stamps are not increasing",
                              "pass a log whose sensor_combined is intact", label)
        # Relative to the first stamp: float64 cannot hold epoch nanoseconds exactly.
        x, xp = (ns - ns[0]).astype(float), (t_acc - ns[0]).astype(float)
        accel = np.stack([np.interp(x, xp, accel[ok, k]) for k in range(3)], axis=1)
        notes.append(f"{label}: accelerometer samples are logged "
                     f"{np.median(rel[ok]):.0f} us from the gyro's; interpolated onto the gyro "
                     "stamps")
    return validate_imu(ns, gyro, accel, Lines(label))


def read_ulog_mocap(path: Path | str, topic: str | None, notes: list[str]) -> MocapPoses:
    """Marker poses of the mocap (or visual) odometry topic, turned into a z-up world."""
    path = Path(path)
    ulog = _open(path, list(MOCAP_TOPICS))
    name, data = _dataset(ulog, path, topic, MOCAP_TOPICS, "mocap", "--mocap-topic")
    label = f"{path} [{name}]"
    if topic is None and name != MOCAP_TOPICS[0]:
        notes.append(f"{label}: no {MOCAP_TOPICS[0]} in the log; using {name}")
    stamp = "timestamp_sample" if "timestamp_sample" in data else "timestamp"
    ns = data[stamp].astype(np.int64) * 1000
    p = _vector(data, "position", 3, ("x", "y", "z"))
    q = _vector(data, "q", 4)
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
    return validate_mocap(ns, q_enu, p_enu, Lines(label))
