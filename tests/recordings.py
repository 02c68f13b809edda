"""Test helpers: write simulated sessions as ROS 1 bags, ROS 2 bags, bare MCAP and PX4 ULog.

Bags are written with ``rosbags`` (its writers produce what ``rosbag record`` / ``ros2 bag
record`` produce). The ULog writer follows PX4's published ULog format spec (file header,
flag bits, format / info / add-logged definitions, then data messages), independent of the
reader under test (``pyulog``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap_calib.core.model.types import ImuSamples, MocapPoses

# --- bags ------------------------------------------------------------------------------------


def _time(ts, ns: int):
    Time = ts.types["builtin_interfaces/msg/Time"]
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


def _header(ts, ns: int, frame: str = "world"):
    Header = ts.types["std_msgs/msg/Header"]
    if "seq" in Header.__dataclass_fields__:  # ROS 1
        return Header(seq=0, stamp=_time(ts, ns), frame_id=frame)
    return Header(stamp=_time(ts, ns), frame_id=frame)


def imu_msg(ts, ns: int, w, a):
    T = ts.types
    V = T["geometry_msgs/msg/Vector3"]
    Q = T["geometry_msgs/msg/Quaternion"]
    return T["sensor_msgs/msg/Imu"](
        header=_header(ts, ns, "imu"), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.zeros(9), angular_velocity=V(x=w[0], y=w[1], z=w[2]),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=V(x=a[0], y=a[1], z=a[2]), linear_acceleration_covariance=np.zeros(9))


def pose_msg(ts, msgtype: str, ns: int, q_wxyz, p, child: str = "drone"):
    """A pose message of ``msgtype`` holding ``T_WM`` (quaternion wxyz, position)."""
    T = ts.types
    Q = T["geometry_msgs/msg/Quaternion"](x=q_wxyz[1], y=q_wxyz[2], z=q_wxyz[3], w=q_wxyz[0])
    P = T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2])
    V3 = T["geometry_msgs/msg/Vector3"]
    pose = T["geometry_msgs/msg/Pose"](position=P, orientation=Q)
    h = _header(ts, ns)
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return T[msgtype](header=h, pose=pose)
    cov = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36))
    if msgtype == "geometry_msgs/msg/PoseWithCovarianceStamped":
        return T[msgtype](header=h, pose=cov)
    if msgtype == "nav_msgs/msg/Odometry":
        tw = T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=V3(x=0.0, y=0.0, z=0.0),
                                                angular=V3(x=0.0, y=0.0, z=0.0)),
            covariance=np.zeros(36))
        return T[msgtype](header=h, child_frame_id=child, pose=cov, twist=tw)
    tr = T["geometry_msgs/msg/TransformStamped"](
        header=h, child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](translation=V3(x=p[0], y=p[1], z=p[2]),
                                                   rotation=Q))
    if msgtype == "geometry_msgs/msg/TransformStamped":
        return tr
    assert msgtype == "tf2_msgs/msg/TFMessage"
    other = T["geometry_msgs/msg/TransformStamped"](
        header=h, child_frame_id="other_body",
        transform=T["geometry_msgs/msg/Transform"](translation=V3(x=1.0, y=2.0, z=3.0),
                                                   rotation=Q))
    return T[msgtype](transforms=[other, tr])


def write_bag(path: Path, kind: str, imu: ImuSamples | None, mocap: MocapPoses | None, *,
              pose_type: str = "geometry_msgs/msg/PoseStamped", imu_topic: str = "/imu0",
              mocap_topic: str = "/vicon/drone/pose", receive_delay_ns: int = 0,
              extra_topics: dict[str, str] | None = None) -> Path:
    """Write a bag: ``kind`` is ``rosbag1``, ``db3``, ``mcap`` (ROS 2 folder) or ``bare_mcap``.

    Record times are the stamps plus ``receive_delay_ns``; ``extra_topics`` (topic -> type)
    adds one message each of further topics (to test topic selection).
    """
    ts = _store(kind)
    msgs: list[tuple[int, str, object]] = []
    if imu is not None:
        for ns, w, a in zip(imu.stamps_ns().tolist(), imu.gyro.tolist(), imu.accel.tolist(),
                            strict=True):
            msgs.append((ns, imu_topic, imu_msg(ts, ns, w, a)))
    if mocap is not None:
        for ns, q, p in zip(mocap.stamps_ns().tolist(), mocap.quat_wxyz.tolist(),
                            mocap.position.tolist(), strict=True):
            msgs.append((ns, mocap_topic, pose_msg(ts, pose_type, ns, q, p)))
    first = msgs[0][0] if msgs else 1_600_000_000_000_000_000
    for i, (topic, msgtype) in enumerate((extra_topics or {}).items()):
        if msgtype == "sensor_msgs/msg/Imu":
            msgs.append((first + i, topic, imu_msg(ts, first + i, (0, 0, 0), (0, 0, 9.8))))
        else:
            msgs.append((first + i, topic, pose_msg(ts, msgtype, first + i, (1, 0, 0, 0),
                                                    (0, 0, 0))))
    return _write(path, kind, ts, msgs, receive_delay_ns)


def _store(kind: str):
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if kind == "rosbag1" else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in ts.types:  # not in rosbags' ROS 1 store
        from rosbags.typesys import get_types_from_msg

        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                       "tf2_msgs/msg/TFMessage"))
    return ts


def _write(path: Path, kind: str, ts, msgs: list[tuple[int, str, object]],
           receive_delay_ns: int) -> Path:
    """Write time-ordered messages with ``rosbags`` (record time = stamp + delay)."""
    msgs.sort(key=lambda m: m[0])
    types = {topic: type(m).__msgtype__ for _, topic, m in msgs}
    if kind == "rosbag1":
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        ser = ts.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2

        plugin = StoragePlugin.SQLITE3 if kind == "db3" else StoragePlugin.MCAP
        folder = path.parent / (path.name + "_folder") if kind == "bare_mcap" else path
        writer = Writer2(folder, version=9, storage_plugin=plugin)
        ser = ts.serialize_cdr
    with writer:
        conns = {topic: writer.add_connection(topic, msgtype, typestore=ts)
                 for topic, msgtype in types.items()}
        for ns, topic, m in msgs:
            writer.write(conns[topic], ns + receive_delay_ns, ser(m, types[topic]))
    if kind == "bare_mcap":
        mcap = next(folder.glob("*.mcap"))
        mcap.rename(path)
        for f in folder.iterdir():
            f.unlink()
        folder.rmdir()
    return path


def transform_msg(ts, ns: int, parent: str, child: str, p, q_wxyz):
    T = ts.types
    V3 = T["geometry_msgs/msg/Vector3"]
    Q = T["geometry_msgs/msg/Quaternion"](x=q_wxyz[1], y=q_wxyz[2], z=q_wxyz[3], w=q_wxyz[0])
    return T["geometry_msgs/msg/TransformStamped"](
        header=_header(ts, ns, parent), child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](translation=V3(x=p[0], y=p[1], z=p[2]),
                                                   rotation=Q))


def write_tf_bag(path: Path, kind: str, imu: ImuSamples | None,
                 tf: list[tuple[int, str, list[tuple[str, str, object, object]]]]) -> Path:
    """A bag whose poses are TF messages: ``tf`` holds (stamp ns, topic, [(parent, child,
    position, quaternion wxyz), ...]) per message, each message stamped (and recorded) at its
    stamp."""
    ts = _store(kind)
    msgs: list[tuple[int, str, object]] = []
    if imu is not None:
        for ns, w, a in zip(imu.stamps_ns().tolist(), imu.gyro.tolist(), imu.accel.tolist(),
                            strict=True):
            msgs.append((ns, "/imu0", imu_msg(ts, ns, w, a)))
    for ns, topic, items in tf:
        trs = [transform_msg(ts, ns, pa, ch, p, q) for pa, ch, p, q in items]
        msgs.append((ns, topic, ts.types["tf2_msgs/msg/TFMessage"](transforms=trs)))
    return _write(path, kind, ts, msgs, 0)


# --- ULog (PX4's published format spec) ------------------------------------------------------

_ULOG_MAGIC = b"ULog\x01\x12\x35"

SENSOR_COMBINED = ("sensor_combined:uint64_t timestamp;float[3] gyro_rad;uint32_t "
                   "gyro_integral_dt;int32_t accelerometer_timestamp_relative;float[3] "
                   "accelerometer_m_s2;uint32_t accelerometer_integral_dt;uint8_t "
                   "accelerometer_clipping;uint8_t gyro_clipping;uint8_t "
                   "accel_calibration_count;uint8_t gyro_calibration_count;")
VEHICLE_ODOMETRY = ("vehicle_odometry:uint64_t timestamp;uint64_t timestamp_sample;float[3] "
                    "position;float[4] q;float[3] velocity;float[3] angular_velocity;float[3] "
                    "position_variance;float[3] orientation_variance;float[3] "
                    "velocity_variance;uint8_t pose_frame;uint8_t velocity_frame;uint8_t "
                    "reset_counter;int8_t quality;uint8_t[4] _padding0;")


def _msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def _info(key: str, value: bytes) -> bytes:
    k = key.encode()
    return _msg(b"I", struct.pack("<B", len(k)) + k + value)


SENSOR_GYRO = ("sensor_gyro:uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;"
               "float x;float y;float z;float temperature;uint32_t error_count;")
SENSOR_ACCEL = SENSOR_GYRO.replace("sensor_gyro:", "sensor_accel:")
SENSOR_SELECTION = ("sensor_selection:uint64_t timestamp;uint32_t accel_device_id;uint32_t "
                    "gyro_device_id;")


@dataclass
class RawImuLog:
    """One IMU's ``sensor_gyro`` / ``sensor_accel`` instances: stamps in us (``timestamp_sample``;
    ``timestamp`` is 200 us later) and values (rad/s, m/s^2), written as float32."""

    gyro_instance: int
    accel_instance: int
    device_id: int
    t_gyro_us: np.ndarray
    gyro: np.ndarray
    t_accel_us: np.ndarray
    accel: np.ndarray
    accel_device_id: int | None = None  # None: the gyro's


class _ULogWriter:
    """Definitions, subscriptions and time-ordered data, dropout and other messages."""

    def __init__(self, t0_us: int) -> None:
        self.head = bytearray(_ULOG_MAGIC + b"\x01" + struct.pack("<Q", t0_us))
        self.head += _msg(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
        self.defs = bytearray()
        self.subs = bytearray()
        self.events: list[tuple[int, int, bytes]] = []
        self.next_id = 0

    def define(self, fmt: str) -> None:
        self.defs += _msg(b"F", fmt.encode())

    def subscribe(self, name: str, multi_id: int = 0) -> int:
        self.subs += _msg(b"A", struct.pack("<BH", multi_id, self.next_id) + name.encode())
        self.next_id += 1
        return self.next_id - 1

    def data(self, msg_id: int, t_us: int, body: bytes) -> None:
        self.events.append((t_us, 0, _msg(b"D", struct.pack("<H", msg_id) + body)))

    def dropout(self, t_us: int, ms: int) -> None:
        """A dropout record right after the data up to ``t_us``."""
        self.events.append((t_us, 1, _msg(b"O", struct.pack("<H", ms))))

    def write(self, path: Path) -> Path:
        out = self.head + self.defs + _info("char[8] sys_name", b"mc-calib") \
            + _info("char[7] ver_hw", b"SIMTEST") + self.subs
        for _, _, m in sorted(self.events, key=lambda e: (e[0], e[1])):
            out += m
        path.write_bytes(bytes(out))
        return path


def write_ulog(path: Path, imu: ImuSamples | None, mocap: MocapPoses | None, *,
               odometry_name: str = "vehicle_mocap_odometry", accel_relative_us: int = 0,
               pose_frame: int = 1, raw: tuple[RawImuLog, ...] = (),
               dropouts: tuple[tuple[int, int], ...] = (),
               selection: tuple[tuple[int, int, int], ...] = ()) -> Path:
    """Write a ULog with ``sensor_combined`` (if ``imu``) and, if given, a mocap odometry topic.

    IMU stamps become microseconds (they must be whole microseconds), values float32 as PX4
    logs them. Mocap poses are written as given (NED world, FRD body) in ``position``/``q``,
    stamped in ``timestamp_sample``; ``timestamp`` is 1 ms later (publication). ``raw`` adds
    ``sensor_gyro``/``sensor_accel`` instances, ``dropouts`` the logger's dropout records
    (time in us, length in ms), ``selection`` ``sensor_selection`` messages (time in us, gyro
    and accel device ids).
    """
    starts = [int(imu.stamps_ns()[0] // 1000)] if imu is not None else []
    starts += [int(r.t_gyro_us[0]) for r in raw]
    w = _ULogWriter(min(starts))
    for fmt in (SENSOR_COMBINED, VEHICLE_ODOMETRY.replace("vehicle_odometry:",
                                                          f"{odometry_name}:"),
                SENSOR_GYRO, SENSOR_ACCEL, SENSOR_SELECTION):
        w.define(fmt)
    if imu is not None:
        _combined(w, imu, accel_relative_us)
    if mocap is not None:
        _odometry(w, mocap, odometry_name, pose_frame)
    for r in raw:
        _raw(w, r)
    if selection:
        sid = w.subscribe("sensor_selection")
        for t, gyro_id, accel_id in selection:
            w.data(sid, t, struct.pack("<QII", t, accel_id, gyro_id))
    for t, ms in dropouts:
        w.dropout(t, ms)
    return w.write(path)


def _combined(w: _ULogWriter, imu: ImuSamples, accel_relative_us: int) -> None:
    imu_us = imu.stamps_ns() // 1000
    assert np.all(imu_us * 1000 == imu.stamps_ns()), "IMU stamps must be whole microseconds"
    sid = w.subscribe("sensor_combined")
    g = imu.gyro.astype(np.float32)
    a = imu.accel.astype(np.float32)
    for i, t in enumerate(imu_us.tolist()):
        w.data(sid, t, struct.pack("<Q3fIi3fIBBBB", t, *g[i], 5000, accel_relative_us, *a[i],
                                   5000, 0, 0, 1, 1))


def _odometry(w: _ULogWriter, mocap: MocapPoses, name: str, pose_frame: int) -> None:
    sid = w.subscribe(name)
    moc_us = mocap.stamps_ns() // 1000
    q = mocap.quat_wxyz.astype(np.float32)
    p = mocap.position.astype(np.float32)
    nan3 = (float("nan"),) * 3
    for i, t in enumerate(moc_us.tolist()):
        w.data(sid, t + 1000, struct.pack("<QQ3f4f3f3f3f3f3fBBBb", t + 1000, t, *p[i], *q[i],
                                          *nan3, *nan3, *nan3, *nan3, *nan3, pose_frame, 0, 0,
                                          100))


def _raw(w: _ULogWriter, r: RawImuLog) -> None:
    accel_id = r.device_id if r.accel_device_id is None else r.accel_device_id
    for name, inst, dev, ts, vals in (("sensor_gyro", r.gyro_instance, r.device_id, r.t_gyro_us,
                                       r.gyro),
                                      ("sensor_accel", r.accel_instance, accel_id, r.t_accel_us,
                                       r.accel)):
        sid = w.subscribe(name, inst)
        v = np.asarray(vals).astype(np.float32)
        for i, t in enumerate(np.asarray(ts).tolist()):
            w.data(sid, t + 200, struct.pack("<QQI3ffI", t + 200, t, dev, *v[i], 25.0, 0))
