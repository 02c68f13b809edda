"""Crazyflie uSD event logs written for tests, from the layout Bitcraze documents
(``tools/usdlog/cfusdlog.py`` of the firmware), independently of the reader."""

from __future__ import annotations

import struct
import zlib

import numpy as np

from mocap_calib.core.model.types import ImuSamples, MocapPoses

GYRO = ("estGyroscope", ("gyro.x(f)", "gyro.y(f)", "gyro.z(f)"))
ACCEL = ("estAcceleration", ("acc.x(f)", "acc.y(f)", "acc.z(f)"))
POSE = ("estPose", ("locSrv.x(f)", "locSrv.y(f)", "locSrv.z(f)", "locSrv.qx(f)",
                    "locSrv.qy(f)", "locSrv.qz(f)", "locSrv.qw(f)"))
BARO = ("estBarometer", ("baro.asl(f)",))


def usd_bytes(events: list[tuple[str, tuple[str, ...]]],
              records: list[tuple[int, int, tuple[float, ...]]], version: int = 2) -> bytes:
    """A uSD log: header, event definitions (ids 0..), records (event index, stamp in the
    version's unit, values), CRC-32."""
    out = bytearray(struct.pack("<BHH", 0xBC, version, len(events)))
    fmts = []
    for eid, (name, fields) in enumerate(events):
        out += struct.pack("<H", eid) + name.encode() + b"\0" + struct.pack("<H", len(fields))
        for f in fields:
            out += f.encode() + b"\0"
        fmts.append("<" + "".join(f[-2] for f in fields))
    head = "<HQ" if version == 2 else "<HI"
    for eid, stamp, values in records:
        out += struct.pack(head, eid, stamp) + struct.pack(fmts[eid], *values)
    return bytes(out + struct.pack("<I", zlib.crc32(out)))


def session_log(imu: ImuSamples, mocap: MocapPoses | None, version: int = 2) -> bytes:
    """A session as the firmware logs it: gyro (deg/s) and accelerometer (g) events on the IMU
    stamps, estPose events (xyzw) on the mocap's, float32 values, one clock (the IMU's)."""
    unit = 1000 if version == 2 else 1_000_000
    t_imu = imu.stamps_ns() // unit
    recs = [(0, int(t), tuple(v)) for t, v in zip(t_imu, np.degrees(imu.gyro), strict=True)]
    recs += [(1, int(t), tuple(v)) for t, v in zip(t_imu, imu.accel / 9.80665, strict=True)]
    if mocap is not None:
        t_pose = mocap.stamps_ns() // unit
        recs += [(2, int(t), (*p, *q[[1, 2, 3, 0]]))
                 for t, p, q in zip(t_pose, mocap.position, mocap.quat_wxyz, strict=True)]
    recs.sort(key=lambda r: r[1])
    return usd_bytes([GYRO, ACCEL, POSE], recs, version)
