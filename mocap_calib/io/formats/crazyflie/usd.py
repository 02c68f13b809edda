"""The IMU and the external pose of a Crazyflie uSD log, read as recorded.

Events (their names are the firmware's; ``--imu-topic`` / ``--mocap-topic`` choose others):

- IMU: ``estGyroscope`` (``gyro.x/y/z``, deg/s) and ``estAcceleration`` (``acc.x/y/z``, g), the
  samples the estimator receives (after the firmware's own bias and scale handling), in the
  body frame (x forward, y left, z up). The two events carry their own stamps: the
  accelerometer is merged onto the gyro's stamps (:mod:`mocap_calib.io.merge`).
  ``--imu-topic GYRO_EVENT,ACCEL_EVENT`` names both; ``--imu-topic EVENT`` one event holding
  both (its ``gyro.*`` and ``acc.*`` fields).
- Poses: ``estPose`` (``locSrv.x/y/z`` in m, ``locSrv.qx/qy/qz/qw``), the external pose (the
  mocap's) sent to the drone over the radio and stamped when it arrived, so the radio's
  latency is part of the clock offset the calibration finds. ``--mocap-topic EVENT`` names
  another event with ``x, y, z`` and ``qx, qy, qz, qw`` fields.

Units (deg/s, g, stamps in ms or us) are the format's, not options. A field is found by the
last part of its name (``gyro.x`` -> ``x``), within the group before the dot (``gyro``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.policy import ACCEL_UNITS, GYRO_UNITS
from mocap_calib.errors import input_error
from mocap_calib.io.formats.crazyflie.usd_file import Event, UsdLog, is_usd_log, read_usd_log
from mocap_calib.io.merge import merge_on_gyro
from mocap_calib.io.reading import Format, ReadOptions
from mocap_calib.io.streams import ImuTable, PoseTable
from mocap_calib.io.validate import Lines

GYRO_EVENT = "estGyroscope"
ACCEL_EVENT = "estAcceleration"
POSE_EVENT = "estPose"
GYRO_UNIT = "deg/s"
ACCEL_UNIT = "g"
_XYZ = ("x", "y", "z")
_QUAT = ("qw", "qx", "qy", "qz")
_IMU_FIX = ("name the IMU's events with --imu-topic GYRO_EVENT,ACCEL_EVENT (or one event "
            "holding gyro.x/y/z and acc.x/y/z)")
_POSE_FIX = ("name the pose event with --mocap-topic EVENT (fields x, y, z and qx, qy, qz, qw), "
             "or log the external pose (estPose) on the Crazyflie")


def _groups(event: Event, names: tuple[str, ...]) -> dict[str, tuple[str, ...]]:
    """Groups (the name before the last dot) holding every one of ``names`` -> their fields."""
    found: dict[str, dict[str, str]] = {}
    for f in event.fields:
        group, _, last = f.rpartition(".")
        found.setdefault(group, {})[last] = f
    return {g: tuple(fields[n] for n in names) for g, fields in found.items()
            if all(n in fields for n in names)}


def _event(log: UsdLog, name: str, option: str, fix: str) -> Event:
    event = log.events.get(name)
    if event is None:
        raise input_error(f"no event '{name}' in the log (events with records: "
                          f"{log.listing()})", f"pass {option} with one of those", str(log.path))
    if not len(event):
        raise input_error(f"event '{name}' has no records in the log (events with records: "
                          f"{log.listing()})", fix, str(log.path))
    return event


def _triad(event: Event, prefix: str, what: str, log: UsdLog) -> tuple[str, ...]:
    """The x, y, z fields of ``what`` in ``event``: its only x/y/z group, or the group whose
    name starts with ``prefix`` (``gyro``, ``acc``)."""
    groups = _groups(event, _XYZ)
    if len(groups) > 1:
        groups = {g: f for g, f in groups.items() if g.lower().startswith(prefix)}
    if len(groups) != 1:
        raise input_error(f"event '{event.name}' has {'no' if not groups else 'several'} "
                          f"x, y, z fields for the {what} (its fields: "
                          f"{', '.join(event.fields) or 'none'})", _IMU_FIX, str(log.path))
    return next(iter(groups.values()))


def _shown(fields: tuple[str, ...]) -> str:
    """``gyro.x/y/z`` for ``(gyro.x, gyro.y, gyro.z)``."""
    group = fields[0].rpartition(".")[0]
    tails = [f.rpartition(".")[2] for f in fields]
    return f"{group}.{'/'.join(tails)}" if group else "/".join(tails)


def _values(event: Event, fields: tuple[str, ...]) -> NDArray[np.float64]:
    return np.stack([event.values[f] for f in fields], axis=1)


def _imu_events(log: UsdLog, spec: str | None) -> tuple[Event, Event]:
    if spec is None:
        missing = [n for n in (GYRO_EVENT, ACCEL_EVENT) if not len(log.events.get(n, ()))]
        if missing:
            raise input_error(f"no {' or '.join(missing)} events in the log (events with "
                              f"records: {log.listing()})", _IMU_FIX, str(log.path))
        return log.events[GYRO_EVENT], log.events[ACCEL_EVENT]
    names = [n.strip() for n in spec.split(",")]
    if len(names) > 2 or not all(names):
        raise input_error(f"--imu-topic '{spec}' names {len(names)} events", _IMU_FIX,
                          str(log.path))
    gyro = _event(log, names[0], "--imu-topic", _IMU_FIX)
    return gyro, _event(log, names[-1], "--imu-topic", _IMU_FIX)


def read_usd_imu(log: UsdLog, spec: str | None, notes: list[str]) -> ImuTable:
    """The IMU samples of a decoded log, on the gyro's stamps (SI units)."""
    g_event, a_event = _imu_events(log, spec)
    g_fields = _triad(g_event, "gyro", "gyro", log)
    a_fields = _triad(a_event, "acc", "accelerometer", log)
    events = g_event.name if g_event is a_event else f"{g_event.name}, {a_event.name}"
    label = f"{log.path} [{events}]"
    ns, gyro, accel = merge_on_gyro(g_event.stamps_ns, _values(g_event, g_fields),
                                    a_event.stamps_ns, _values(a_event, a_fields),
                                    label=label, notes=notes)
    notes.append(f"{log.path}: IMU from {g_event.name} ({_shown(g_fields)}, {GYRO_UNIT}) and "
                 f"{a_event.name} ({_shown(a_fields)}, {ACCEL_UNIT}), the units of the "
                 "Crazyflie's log")
    return ImuTable(ns, gyro * GYRO_UNITS[GYRO_UNIT], accel * ACCEL_UNITS[ACCEL_UNIT],
                    Lines(label), time_unit="ms" if log.version == 1 else "us",
                    gyro_unit=GYRO_UNIT, accel_unit=ACCEL_UNIT, note_gaps=True)


def read_usd_poses(log: UsdLog, spec: str | None, notes: list[str]) -> PoseTable:
    """The external poses of a decoded log (``[w, x, y, z]``, metres)."""
    name = spec.strip() if spec is not None else POSE_EVENT
    if spec is None and not len(log.events.get(POSE_EVENT, ())):
        raise input_error(f"no {POSE_EVENT} events in the log, so no external (mocap) pose "
                          f"(events with records: {log.listing()})", _POSE_FIX, str(log.path))
    event = _event(log, name, "--mocap-topic", _POSE_FIX)
    pos, quat = _groups(event, _XYZ), _groups(event, _QUAT)
    both = sorted(set(pos) & set(quat))
    if len(both) != 1:
        raise input_error(f"event '{event.name}' has {'no' if not both else 'several'} pose "
                          f"fields (x, y, z and qx, qy, qz, qw of one group; its fields: "
                          f"{', '.join(event.fields) or 'none'})", _POSE_FIX, str(log.path))
    label = f"{log.path} [{event.name}]"
    notes.append(f"{log.path}: poses from {event.name} ({_shown(pos[both[0]])} in m, "
                 f"quaternion {_shown(quat[both[0]][1:] + quat[both[0]][:1])}), stamped when "
                 "each pose reached the drone: the radio's latency is part of the clock offset")
    return PoseTable(event.stamps_ns, _values(event, quat[both[0]]), _values(event, pos[both[0]]),
                     Lines(label), time_unit="ms" if log.version == 1 else "us")


# --- the registry's record -------------------------------------------------------------------

def _imu(path: Path, opts: ReadOptions, notes: list[str]) -> ImuTable:
    return read_usd_imu(read_usd_log(path), opts.recording.imu_topic, notes)


def _poses(path: Path, opts: ReadOptions, notes: list[str]) -> PoseTable:
    return read_usd_poses(read_usd_log(path), opts.recording.mocap_topic, notes)


def _both(path: Path, opts: ReadOptions, notes: list[str]) -> tuple[ImuTable, PoseTable]:
    log = read_usd_log(path)
    return (read_usd_imu(log, opts.recording.imu_topic, notes),
            read_usd_poses(log, opts.recording.mocap_topic, notes))


FORMAT = Format("crazyflie", "Crazyflie uSD log", lambda p: p.is_file() and is_usd_log(p),
                _imu, _poses, _both, frozenset({"imu_topic", "mocap_topic"}),
                own_units="its own units: deg/s, g, ms")
