"""ROS 1 bags, ROS 2 bags (db3 or MCAP storage) and bare MCAP files, read with ``rosbags``.

No ROS installation is needed: ``rosbags`` parses the containers and the message definitions
the bags carry. The IMU comes from a ``sensor_msgs/Imu`` topic; the mocap from a
``geometry_msgs/PoseStamped``, ``TransformStamped``, ``PoseWithCovarianceStamped``,
``nav_msgs/Odometry`` or ``tf2_msgs/TFMessage`` topic (``/tf`` with ``mocap_frame`` naming the
marker body's frame, ``CHILD`` or ``PARENT:CHILD``: the chain of transforms between them is
composed, ``/tf_static`` included; :mod:`.ros.tf`). A topic left unnamed is taken when exactly
one topic of a usable type exists (``/tf_static`` is never the pose stream).

Reading is in bulk: the container hands over each topic's serialised messages and
:mod:`.ros.wire` decodes them all at once with numpy from the known layouts (one message at a
time only for definitions that differ from the standard ones).

Stamps come from ``header.stamp`` (``stamp="header"``) or from the bag's record time
(``stamp="receive"``). Messages whose header stamps arrive out of order are sorted (and counted
in the notes); repeated stamps stay an error, as in the CSV readers. Dropped IMU messages are
gaps in the stream, noted, not refused: the calibration handles them.
"""

from __future__ import annotations

import sqlite3
import struct
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.errors import InputError, input_error
from mocap_calib.io.formats.ros.tf import chain, compose, frame, links, parse_frames
from mocap_calib.io.formats.ros.tf_wire import Transforms, deserialise_tf, read_tf
from mocap_calib.io.formats.ros.wire import deserialise_fixed, read_fixed
from mocap_calib.io.reading import Format, ReadOptions, RecordingOptions
from mocap_calib.io.streams import ImuTable, PoseTable
from mocap_calib.io.validate import Lines

__all__ = ["RecordingOptions", "open_bag", "read_bag_imu", "read_bag_mocap"]  # re-exported

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

    @property
    def ros1(self) -> bool:
        return self.kind == "rosbag1"

    def raw(self, topic: str) -> tuple[np.ndarray, list[bytes]]:
        """Record times (ns) and serialised bytes of every message on ``topic``, in one pass
        (the container's reader yields one message at a time; nothing else is done per
        message here)."""
        conns = [c for c in self.connections if c.topic == topic]
        it = (self._mcap.messages(conns) if self.kind == "mcap"
              else self._any.messages(connections=conns))
        times: list[int] = []
        raws: list[bytes] = []
        add_t, add_r = times.append, raws.append
        for _, t_ns, data in it:
            add_t(t_ns)
            add_r(data)
        return np.array(times, dtype=np.int64), raws

    def deserialiser(self, msgtype: str) -> Callable[[bytes], Any]:
        """Bytes -> message of ``msgtype`` (ROS 1 messages come out with ROS 2 field names)."""
        if self.kind == "mcap":
            return lambda raw: self.typestore.deserialize_cdr(raw, msgtype)
        return lambda raw: self._any.deserialize(raw, msgtype)


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
    candidates = sorted(t for t, ty in bag.topics.items() if ty in types
                        and not (what == "mocap" and _is_static(t, ty)))
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


def _sorted(ns: np.ndarray, notes: list[str], label: str) -> np.ndarray:
    """Stable order by stamp (header stamps can arrive out of order)."""
    order = np.argsort(ns, kind="stable")
    moved = int(np.count_nonzero(order != np.arange(len(ns))))
    if moved:
        notes.append(f"{label}: {moved} messages were out of stamp order and were sorted")
    return order


def _fields(bag: _Bag, topic: str, label: str, what: str
            ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Record times, header stamps and the float64 fields of every message on ``topic``:
    in bulk from the bytes, or message by message if the bulk reading does not apply."""
    t_rec, raws = bag.raw(topic)
    if not raws:
        raise input_error("the topic has no messages", f"pass a topic that holds the {what}",
                          label)
    msgtype = bag.topics[topic]
    deserialise = bag.deserialiser(msgtype)
    got = read_fixed(raws, msgtype, bag.ros1, deserialise)
    stamps, fields = got if got is not None else deserialise_fixed(raws, msgtype, deserialise)
    return t_rec, stamps, fields


def read_bag_imu(bag: _Bag, opts: RecordingOptions, notes: list[str]) -> ImuSamples:
    """The checked IMU samples of a ``sensor_msgs/Imu`` topic (:func:`bag_imu_table`)."""
    table = bag_imu_table(bag, opts, notes)
    imu = table.validate()
    notes.extend(table.notes(imu))
    return imu


def bag_imu_table(bag: _Bag, opts: RecordingOptions, notes: list[str]) -> ImuTable:
    """The IMU samples of a ``sensor_msgs/Imu`` topic. Dropped messages (gaps) are kept as
    gaps, with a note: the calibration handles them."""
    _check_stamp(opts.stamp)
    topic = pick_topic(bag, opts.imu_topic, IMU_TYPES, "IMU", "--imu-topic")
    label = f"{bag.path} [{topic}]"
    t_rec, stamps, f = _fields(bag, topic, label, "IMU stream")
    if opts.stamp == "receive":
        stamps = t_rec
    order = _sorted(stamps, notes, label)
    return ImuTable(stamps[order], f["gyro"][order], f["accel"][order], Lines(label),
                    note_gaps=True)


def read_bag_mocap(bag: _Bag, opts: RecordingOptions, notes: list[str]) -> MocapPoses:
    """The checked marker poses of a pose topic (:func:`bag_pose_table`)."""
    return bag_pose_table(bag, opts, notes).validate()


def bag_pose_table(bag: _Bag, opts: RecordingOptions, notes: list[str]) -> PoseTable:
    """The marker poses ``T_WM`` of a pose topic, or composed along a TF chain."""
    _check_stamp(opts.stamp)
    topic = pick_topic(bag, opts.mocap_topic, POSE_TYPES, "mocap", "--mocap-topic")
    label = f"{bag.path} [{topic}]"
    if POSE_TYPES[bag.topics[topic]] == "tf":
        stamps, q, p = _tf_poses(bag, topic, opts, notes)
    else:
        if opts.mocap_frame is not None:
            notes.append(f"ignored --mocap-frame: {topic} is not a TF topic")
        t_rec, stamps, f = _fields(bag, topic, label, "mocap poses")
        if opts.stamp == "receive":
            stamps = t_rec
        p, q = f["position"], f["orientation"][:, [3, 0, 1, 2]]
    order = _sorted(stamps, notes, label)
    return PoseTable(stamps[order], np.ascontiguousarray(q[order]),
                     np.ascontiguousarray(p[order]), Lines(label))


def _tf(bag: _Bag, topic: str) -> tuple[np.ndarray, Transforms]:
    t_rec, raws = bag.raw(topic)
    deserialise = bag.deserialiser(bag.topics[topic])
    tf = read_tf(raws, bag.ros1, deserialise)
    return t_rec, tf if tf is not None else deserialise_tf(raws, deserialise)


def _tf_poses(bag: _Bag, topic: str, opts: RecordingOptions, notes: list[str]
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Poses of the TF chain ``--mocap-frame`` names (see :mod:`.ros.tf`)."""
    src = str(bag.path)
    t_rec, tf = _tf(bag, topic)
    statics = [t for t, ty in bag.topics.items() if t != topic and _is_static(t, ty)]
    static = _tf(bag, statics[0])[1] if statics else None
    children: dict[str, int] = {}
    for tr in (tf, static) if static is not None else (tf,):
        codes, counts = np.unique(tr.child, return_counts=True)
        for c, n in zip(codes.tolist(), counts.tolist(), strict=True):
            children[frame(tr.names[c])] = children.get(frame(tr.names[c]), 0) + n
    listed = ", ".join(f"{c} ({n})" for c, n in sorted(children.items())) or "none"
    if opts.mocap_frame is None:
        raise input_error(f"{topic} is a TF topic; say which child frame is the marker body "
                          f"(child frames: {listed})", "pass --mocap-frame CHILD (or "
                          "PARENT:CHILD)", src)
    parent, child = parse_frames(opts.mocap_frame)
    if child not in children:
        raise input_error(f"no transform with child frame '{child}' on {topic} (child frames: "
                          f"{listed})", "pass --mocap-frame with one of those", src)
    stamps = t_rec[tf.message] if opts.stamp == "receive" else tf.stamp
    tree = links(tf, stamps, static, topic, src)
    down_c, down_p, parent = chain(tree, parent, child, topic, src)
    t, q, p, more = compose(down_c, down_p, src)
    notes.extend(more)
    if len(down_c) + len(down_p) > 1:
        path = (" <- ".join([parent, *[lk.parent for lk in reversed(down_p)]])
                + "".join(f" -> {lk.child}" for lk in down_c))
        notes.append(f"{src} [{topic}]: poses of {child} in {parent}, composed along {path}"
                     f"{' (with /tf_static)' if static is not None else ''}")
    return t, q, p


def _is_static(topic: str, msgtype: str) -> bool:
    return msgtype == "tf2_msgs/msg/TFMessage" and topic.rstrip("/").endswith("tf_static")


def _check_stamp(stamp: str) -> None:
    if stamp not in STAMP_SOURCES:
        raise InputError(f"unknown --stamp '{stamp}'; use header (message stamps) or receive "
                         "(the bag's record time)")


# --- the registry's records ------------------------------------------------------------------

def _imu(path: Path, opts: ReadOptions, notes: list[str]) -> ImuTable:
    with open_bag(path) as bag:
        return bag_imu_table(bag, opts.recording, notes)


def _poses(path: Path, opts: ReadOptions, notes: list[str]) -> PoseTable:
    with open_bag(path) as bag:
        return bag_pose_table(bag, opts.recording, notes)


def _both(path: Path, opts: ReadOptions, notes: list[str]) -> tuple[ImuTable, PoseTable]:
    with open_bag(path) as bag:
        return (bag_imu_table(bag, opts.recording, notes),
                bag_pose_table(bag, opts.recording, notes))


def _format(key: str, name: str) -> Format:
    return Format(key, name, lambda p: bag_kind(p) == key, _imu, _poses, _both,
                  frozenset({"imu_topic", "mocap_topic", "mocap_frame", "stamp"}))


ROSBAG1 = _format("rosbag1", "ROS 1 bag")
ROSBAG2 = _format("rosbag2", "ROS 2 bag")
MCAP = _format("mcap", "MCAP file")
