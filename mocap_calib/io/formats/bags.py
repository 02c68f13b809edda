"""ROS 1 bags, ROS 2 bags (db3 or MCAP storage) and bare MCAP files, read with ``rosbags``.

No ROS installation is needed: ``rosbags`` parses the containers and the message definitions
the bags carry. The IMU comes from a ``sensor_msgs/Imu`` topic; the mocap from a
``geometry_msgs/PoseStamped``, ``TransformStamped``, ``PoseWithCovarianceStamped``,
``nav_msgs/Odometry`` or ``tf2_msgs/TFMessage`` topic (``/tf`` with ``mocap_frame`` naming the
child frame). A topic left unnamed is taken when exactly one topic of a usable type exists.

Stamps come from ``header.stamp`` (``stamp="header"``) or from the bag's record time
(``stamp="receive"``). Messages whose header stamps arrive out of order are sorted (and counted
in the notes); repeated stamps stay an error, as in the CSV readers.
"""

from __future__ import annotations

import sqlite3
import struct
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.errors import InputError, input_error
from mocap_calib.io.checks import Lines, validate_imu, validate_mocap

IMU_TYPES = ("sensor_msgs/msg/Imu",)
#: Pose message types -> where the pose sits in the message.
POSE_TYPES: dict[str, str] = {
    "geometry_msgs/msg/PoseStamped": "pose",
    "geometry_msgs/msg/PoseWithCovarianceStamped": "pose.pose",
    "nav_msgs/msg/Odometry": "pose.pose",
    "geometry_msgs/msg/TransformStamped": "transform",
    "tf2_msgs/msg/TFMessage": "tf",
}
STAMP_SOURCES = ("header", "receive")
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_BAG1_MAGIC = b"#ROSBAG V2.0"


@dataclass(frozen=True)
class RecordingOptions:
    """How to read bags and logs: topics, the TF child frame and the stamp source.

    Attributes:
        imu_topic: IMU topic (None: the only ``sensor_msgs/Imu`` topic).
        mocap_topic: pose topic (None: the only pose topic, ``/tf`` last).
        mocap_frame: child frame of the marker body in a ``TFMessage`` topic.
        stamp: ``header`` (message header stamps) or ``receive`` (the bag's record time).
    """

    imu_topic: str | None = None
    mocap_topic: str | None = None
    mocap_frame: str | None = None
    stamp: str = "header"


def bag_kind(path: Path | str) -> str | None:
    """``rosbag1``, ``rosbag2`` (a folder with ``metadata.yaml``, or a file in it), ``mcap``
    (a bare ``.mcap`` file) or None for anything else."""
    path = Path(path)
    if path.is_dir():
        return "rosbag2" if (path / "metadata.yaml").is_file() else None
    if path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").is_file():
        return "rosbag2"
    if not path.is_file():
        return "rosbag1" if path.suffix == ".bag" else ("mcap" if path.suffix == ".mcap"
                                                          else None)
    with open(path, "rb") as f:
        head = f.read(13)
    if head.startswith(_BAG1_MAGIC) or path.suffix == ".bag":
        return "rosbag1"
    if head.startswith(_MCAP_MAGIC) or path.suffix == ".mcap":
        return "mcap"
    return None


def _read_errors() -> tuple[type[BaseException], ...]:
    """Exceptions a damaged or truncated container raises inside rosbags."""
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as ReaderError1
    from rosbags.rosbag2 import ReaderError as ReaderError2
    from rosbags.serde import SerdeError

    return (AnyReaderError, ReaderError1, ReaderError2, SerdeError, sqlite3.Error, struct.error,
            EOFError, OSError, ValueError, KeyError, IndexError, AssertionError)


class _Bag:
    """An open bag: its topics, its messages and a deserializer, whatever the container."""

    def __init__(self, path: Path, kind: str) -> None:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        self.path = path
        self.kind = kind
        if kind == "mcap":
            from rosbags.rosbag2.storage_mcap import McapReader

            self._mcap = McapReader(path)
            self._mcap.open()
            self.connections = list(self._mcap.connections)
            self.typestore = _typestore(self.connections)
            self.message_count = sum(c.msgcount for c in self.connections)
        else:
            root = path.parent if kind == "rosbag2" and path.is_file() else path
            self._any = AnyReader([root], default_typestore=get_typestore(Stores.LATEST))
            self._any.open()
            self.connections = list(self._any.connections)
            self.typestore = self._any.typestore
            self.message_count = self._any.message_count
        self.topics: dict[str, str] = {c.topic: c.msgtype for c in self.connections}
        self.counts: dict[str, int] = {}
        for c in self.connections:
            self.counts[c.topic] = self.counts.get(c.topic, 0) + c.msgcount

    def close(self) -> None:
        if self.kind == "mcap":
            self._mcap.close()
        else:
            self._any.close()

    def messages(self, topic: str) -> Iterator[tuple[int, Any]]:
        """(record time in ns, deserialized message) of every message on ``topic``."""
        conns = [c for c in self.connections if c.topic == topic]
        if self.kind == "mcap":
            for conn, t_ns, raw in self._mcap.messages(conns):
                yield t_ns, self.typestore.deserialize_cdr(raw, conn.msgtype)
        else:
            for conn, t_ns, raw in self._any.messages(connections=conns):
                yield t_ns, self._any.deserialize(raw, conn.msgtype)


def _typestore(connections: list) -> Any:
    """A typestore holding the message definitions an MCAP file carries (as AnyReader does)."""
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

    types: dict = {}
    for c in connections:
        if c.msgdef.format == MessageDefinitionFormat.MSG:
            types.update(get_types_from_msg(c.msgdef.data, c.msgtype))
        elif c.msgdef.format == MessageDefinitionFormat.IDL:
            sep = "=" * 80 + "\n"
            blocks = (c.msgdef.data.split(sep)[1:] if c.msgdef.data.startswith(f"{sep}IDL: ")
                      else ["\n" + c.msgdef.data])
            for block in blocks:
                types.update(get_types_from_idl(block.split("\n", 1)[1]))
    if not types:
        return get_typestore(Stores.LATEST)
    store = get_typestore(Stores.EMPTY)
    store.register(types)
    return store


@contextmanager
def open_bag(path: Path | str) -> Iterator[_Bag]:
    """Open a bag of any kind, turning container errors into one-line :class:`InputError`."""
    path = Path(path)
    kind = bag_kind(path)
    if kind is None:
        raise input_error("not a ROS bag or MCAP file", "pass a .bag file, a ROS 2 bag folder "
                          "(with metadata.yaml) or a .mcap file", str(path))
    if not path.exists():
        raise input_error("file not found", "check the path", str(path))
    errors = _read_errors()
    try:
        bag = _Bag(path, kind)
    except errors as err:
        raise _damaged(path, kind, err) from None
    try:
        yield bag
    except errors as err:
        raise _damaged(path, kind, err) from None
    finally:
        try:
            bag.close()
        except errors:
            pass


def _damaged(path: Path, kind: str, err: BaseException) -> InputError:
    if isinstance(err, InputError):
        return err
    detail = " ".join(str(err).split()) or type(err).__name__
    fix = "copy the complete recording again"
    if kind == "rosbag1":
        fix += " (a bag whose recorder was killed needs 'rosbag reindex' first)"
    return input_error(f"cannot read the bag ({detail[:160]}): it is truncated, damaged or not "
                       "a bag", fix, str(path))


def _describe_topics(bag: _Bag) -> str:
    if not bag.topics:
        return "none"
    return ", ".join(f"{t} ({ty.replace('/msg/', '/')}, {bag.counts.get(t, 0)})"
                     for t, ty in sorted(bag.topics.items()))


def pick_topic(bag: _Bag, wanted: str | None, types: tuple[str, ...] | dict[str, str],
               what: str, option: str) -> str:
    """The topic to read: ``wanted`` if it exists with a usable type, else the only candidate.

    Raises:
        InputError: no such topic, a topic of another type, none or several candidates.
    """
    src = str(bag.path)
    if bag.message_count == 0 or not bag.topics:
        raise input_error("the bag holds no messages (an empty recording)",
                          "pass the bag that holds the session", src)
    names = ", ".join(t.replace("/msg/", "/") for t in types)
    candidates = sorted(t for t, ty in bag.topics.items() if ty in types)
    listed = ", ".join(candidates) if candidates else "none"
    if wanted is not None:
        topic = wanted if wanted in bag.topics else (
            "/" + wanted if "/" + wanted in bag.topics else None)
        if topic is None:
            raise input_error(f"no topic '{wanted}' in the bag (its topics: "
                              f"{_describe_topics(bag)})",
                              f"pass {option} with a {what} topic ({listed})", src)
        if bag.topics[topic] not in types:
            raise input_error(f"topic '{topic}' is {bag.topics[topic].replace('/msg/', '/')}; "
                              f"the {what} stream must be {names}",
                              f"pass {option} with one of: {listed}", src)
        return topic
    if what == "mocap" and len(candidates) > 1:
        not_tf = [t for t in candidates if bag.topics[t] != "tf2_msgs/msg/TFMessage"]
        candidates = not_tf if len(not_tf) == 1 else candidates
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        raise input_error(f"no {what} topic ({names}) in the bag (its topics: "
                          f"{_describe_topics(bag)})",
                          f"record the {what} stream, or pass {option} if it is there under "
                          "another type", src)
    raise input_error(f"{len(candidates)} topics could be the {what} stream: {listed}",
                      f"choose one with {option}", src)


def _stamp_ns(msg: Any) -> int:
    st = msg.header.stamp
    return int(st.sec) * 1_000_000_000 + int(st.nanosec)


def _sorted(ns: np.ndarray, notes: list[str], label: str) -> np.ndarray:
    """Stable order by stamp (header stamps can arrive out of order)."""
    order = np.argsort(ns, kind="stable")
    moved = int(np.count_nonzero(order != np.arange(len(ns))))
    if moved:
        notes.append(f"{label}: {moved} messages were out of stamp order and were sorted")
    return order


def read_bag_imu(bag: _Bag, opts: RecordingOptions, notes: list[str]) -> ImuSamples:
    """The IMU samples of a ``sensor_msgs/Imu`` topic."""
    _check_stamp(opts.stamp)
    topic = pick_topic(bag, opts.imu_topic, IMU_TYPES, "IMU", "--imu-topic")
    ns, gyro, accel = [], [], []
    for t_rec, m in bag.messages(topic):
        ns.append(t_rec if opts.stamp == "receive" else _stamp_ns(m))
        w, a = m.angular_velocity, m.linear_acceleration
        gyro.append((w.x, w.y, w.z))
        accel.append((a.x, a.y, a.z))
    label = f"{bag.path} [{topic}]"
    stamps = np.asarray(ns, dtype=np.int64)
    order = _sorted(stamps, notes, label)
    lines = Lines(label)
    if len(stamps) == 0:
        raise lines.error("the topic has no messages", "pass a topic that holds the IMU stream")
    return validate_imu(stamps[order], np.asarray(gyro, dtype=float)[order],
                        np.asarray(accel, dtype=float)[order], lines)


def _pose_of(m: Any, where: str) -> tuple[Any, Any]:
    """(position-like, quaternion-like) of a pose message."""
    if where == "transform":
        return m.transform.translation, m.transform.rotation
    pose = m.pose.pose if where == "pose.pose" else m.pose
    return pose.position, pose.orientation


def _frame(name: str) -> str:
    return name.lstrip("/")


def read_bag_mocap(bag: _Bag, opts: RecordingOptions, notes: list[str]) -> MocapPoses:
    """The marker poses ``T_WM`` of a pose topic (or of one child frame of a TF topic)."""
    _check_stamp(opts.stamp)
    topic = pick_topic(bag, opts.mocap_topic, POSE_TYPES, "mocap", "--mocap-topic")
    where = POSE_TYPES[bag.topics[topic]]
    label = f"{bag.path} [{topic}]"
    rows: list[tuple[float, ...]] = []
    ns: list[int] = []
    children: dict[str, int] = {}
    for t_rec, m in bag.messages(topic):
        items = m.transforms if where == "tf" else [m]
        for tr in items:
            if where == "tf":
                child = _frame(tr.child_frame_id)
                children[child] = children.get(child, 0) + 1
                if opts.mocap_frame is None or child != _frame(opts.mocap_frame):
                    continue
                p, q = tr.transform.translation, tr.transform.rotation
                stamp = _stamp_ns(tr)
            else:
                p, q = _pose_of(tr, where)
                stamp = _stamp_ns(tr)
            ns.append(t_rec if opts.stamp == "receive" else stamp)
            rows.append((q.w, q.x, q.y, q.z, p.x, p.y, p.z))
    if where == "tf":
        _check_tf_frame(bag, topic, opts.mocap_frame, children)
    elif opts.mocap_frame is not None:
        notes.append(f"ignored --mocap-frame: {topic} is not a TF topic")
    lines = Lines(label)
    if not ns:
        raise lines.error("the topic has no messages", "pass a topic that holds the mocap poses")
    stamps = np.asarray(ns, dtype=np.int64)
    order = _sorted(stamps, notes, label)
    data = np.asarray(rows, dtype=float)[order]
    return validate_mocap(stamps[order], np.ascontiguousarray(data[:, :4]),
                          np.ascontiguousarray(data[:, 4:]), lines)


def _check_tf_frame(bag: _Bag, topic: str, frame: str | None, children: dict[str, int]) -> None:
    listed = ", ".join(f"{c} ({n})" for c, n in sorted(children.items())) or "none"
    if frame is None:
        raise input_error(f"{topic} is a TF topic; say which child frame is the marker body "
                          f"(child frames: {listed})", "pass --mocap-frame CHILD",
                          str(bag.path))
    if _frame(frame) not in children:
        raise input_error(f"no transform with child frame '{frame}' on {topic} (child frames: "
                          f"{listed})", "pass --mocap-frame with one of those", str(bag.path))


def _check_stamp(stamp: str) -> None:
    if stamp not in STAMP_SOURCES:
        raise InputError(f"unknown --stamp '{stamp}'; use header (message stamps) or receive "
                         "(the bag's record time)")
