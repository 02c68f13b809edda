"""Benchmark: reading a long bag (IMU + mocap) with mocap-calib's bag reader.

Writes, with ``rosbags``, a session of ``--minutes`` (default 30) with a ``sensor_msgs/Imu``
topic at ``--imu-rate`` (200 Hz) and a mocap topic at ``--mocap-rate`` (100 Hz) as a ROS 1 bag
and as a bare ROS 2 MCAP file (and, with ``--tf``, the mocap as ``/tf`` under a static
``/tf_static`` link: world -> mocap_origin -> drone). Then times
``load_inputs(bag, bag)`` (both streams, with every input check) ``--repeats`` times in this
process and prints the best and the median, and checks that the values read are the values
written (bit for bit; for ``/tf``, to 1e-12 after composing the chain).

The machine may be shared: the figures are wall times and move with other load. Prints the
table of docs/validation.md (``--write-doc`` rewrites its section there).

Usage: python scripts/bench_bags.py [--minutes M] [--repeats N] [--tf] [--keep DIR]
       [--write-doc] [--doc PATH]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import _doc_section as doc
import numpy as np

from mocap_calib.io.formats.bags import RecordingOptions
from mocap_calib.io.loader import load_inputs

T0_NS = 1_700_000_000_000_000_000

SECTIONS = ("bench_bags",)


def _session(minutes: float, imu_hz: float, mocap_hz: float, seed: int = 0) -> dict:
    """Smooth synthetic streams (the reader does not care about physics), seeded."""
    rng = np.random.default_rng(seed)
    n_i, n_m = int(minutes * 60 * imu_hz), int(minutes * 60 * mocap_hz)
    ti = T0_NS + np.round(np.arange(n_i) * 1e9 / imu_hz).astype(np.int64)
    tm = T0_NS + np.round(np.arange(n_m) * 1e9 / mocap_hz).astype(np.int64)
    s = (tm - T0_NS) * 1e-9
    half = 0.5 * np.stack([0.3 * np.sin(0.7 * s), 0.2 * np.sin(1.1 * s), 0.9 * np.sin(0.3 * s)],
                          axis=1)
    c = np.cos(np.linalg.norm(half, axis=1))
    q = np.concatenate([c[:, None], half], axis=1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    p = np.stack([np.sin(0.5 * s), np.cos(0.4 * s), 1.0 + 0.2 * np.sin(0.9 * s)], axis=1)
    return {"ti": ti, "gyro": rng.normal(0.0, 0.5, (n_i, 3)),
            "accel": rng.normal(0.0, 0.5, (n_i, 3)) + [0.0, 0.0, 9.81],
            "tm": tm, "q": q, "p": p}


def _store(ros1: bool):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in ts.types:
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                       "tf2_msgs/msg/TFMessage"))
    return ts


def _header(ts, ns: int, frame: str):
    T = ts.types
    stamp = T["builtin_interfaces/msg/Time"](sec=int(ns // 1_000_000_000),
                                             nanosec=int(ns % 1_000_000_000))
    if "seq" in T["std_msgs/msg/Header"].__dataclass_fields__:
        return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def _messages(ts, d: dict, tf: bool):
    """(ns, topic, msgtype, message) in time order."""
    T = ts.types
    V, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    z9 = np.zeros(9)
    out = []
    for ns, w, a in zip(d["ti"].tolist(), d["gyro"].tolist(), d["accel"].tolist(), strict=True):
        out.append((ns, "/imu", "sensor_msgs/msg/Imu", T["sensor_msgs/msg/Imu"](
            header=_header(ts, ns, "imu"), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=z9, angular_velocity=V(x=w[0], y=w[1], z=w[2]),
            angular_velocity_covariance=z9, linear_acceleration=V(x=a[0], y=a[1], z=a[2]),
            linear_acceleration_covariance=z9)))
    for ns, q, p in zip(d["tm"].tolist(), d["q"].tolist(), d["p"].tolist(), strict=True):
        rot = Q(x=q[1], y=q[2], z=q[3], w=q[0])
        if tf:
            tr = T["geometry_msgs/msg/TransformStamped"](
                header=_header(ts, ns, "mocap_origin"), child_frame_id="drone",
                transform=T["geometry_msgs/msg/Transform"](
                    translation=V(x=p[0], y=p[1], z=p[2]), rotation=rot))
            out.append((ns, "/tf", "tf2_msgs/msg/TFMessage",
                        T["tf2_msgs/msg/TFMessage"](transforms=[tr])))
        else:
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]), orientation=rot)
            out.append((ns, "/mocap/pose", "geometry_msgs/msg/PoseStamped",
                        T["geometry_msgs/msg/PoseStamped"](header=_header(ts, ns, "world"),
                                                           pose=pose)))
    if tf:  # identity link world -> mocap_origin: the composed poses equal the written ones
        tr = T["geometry_msgs/msg/TransformStamped"](
            header=_header(ts, T0_NS, "world"), child_frame_id="mocap_origin",
            transform=T["geometry_msgs/msg/Transform"](translation=V(x=0.0, y=0.0, z=0.0),
                                                       rotation=Q(x=0.0, y=0.0, z=0.0, w=1.0)))
        out.append((T0_NS, "/tf_static", "tf2_msgs/msg/TFMessage",
                    T["tf2_msgs/msg/TFMessage"](transforms=[tr])))
    out.sort(key=lambda m: m[0])
    return out


def write(path: Path, kind: str, d: dict, tf: bool) -> Path:
    """A ROS 1 bag (``rosbag1``) or a bare MCAP file (``mcap``) of the session."""
    ros1 = kind == "rosbag1"
    path.unlink(missing_ok=True)
    ts = _store(ros1)
    msgs = _messages(ts, d, tf)
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2

        folder = path.parent / (path.name + "_folder")
        writer = Writer2(folder, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer:
        conns = {}
        for _, topic, msgtype, _ in msgs:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
        for ns, topic, msgtype, m in msgs:
            writer.write(conns[topic], ns, ser(m, msgtype))
    if not ros1:
        next(folder.glob("*.mcap")).rename(path)
        shutil.rmtree(folder)
    return path


def read(path: Path, tf: bool) -> tuple[float, object, object]:
    opts = RecordingOptions(imu_topic="/imu", mocap_topic="/tf" if tf else "/mocap/pose",
                            mocap_frame="world:drone" if tf else None)
    t0 = time.perf_counter()
    imu, mocap, _ = load_inputs(path, path, None, recording=opts)
    return time.perf_counter() - t0, imu, mocap


def check(imu, mocap, d: dict, tf: bool) -> None:
    assert np.array_equal(imu.stamps_ns(), d["ti"]) and np.array_equal(imu.gyro, d["gyro"])
    assert np.array_equal(imu.accel, d["accel"]) and np.array_equal(mocap.stamps_ns(), d["tm"])
    if not tf:
        assert np.array_equal(mocap.position, d["p"]) and np.array_equal(mocap.quat_wxyz, d["q"])
        return
    assert np.max(np.abs(mocap.position - d["p"])) <= 1e-12
    assert np.max(np.abs(np.abs(np.sum(mocap.quat_wxyz * d["q"], axis=1)) - 1.0)) <= 1e-12


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--imu-rate", type=float, default=200.0)
    ap.add_argument("--mocap-rate", type=float, default=100.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tf", action="store_true", help="also time a /tf + /tf_static mocap")
    ap.add_argument("--keep", type=Path, help="write the bags here (default: a temporary dir)")
    doc.add_doc_options(ap)
    a = ap.parse_args()
    doc.check(a, list(SECTIONS))
    d = _session(a.minutes, a.imu_rate, a.mocap_rate)
    print(f"{a.minutes:g} min: {len(d['ti'])} IMU messages at {a.imu_rate:g} Hz, "
          f"{len(d['tm'])} mocap messages at {a.mocap_rate:g} Hz")
    folder = a.keep or Path(tempfile.mkdtemp(prefix="bench_bags_"))
    folder.mkdir(parents=True, exist_ok=True)
    cases = [("rosbag1", False), ("mcap", False)] + ([("rosbag1", True), ("mcap", True)]
                                                      if a.tf else [])
    best: dict[tuple[str, bool], float] = {}
    sizes: dict[str, list[float]] = {}
    try:
        for kind, tf in cases:
            name = f"bench{'_tf' if tf else ''}.{'bag' if kind == 'rosbag1' else 'mcap'}"
            t0 = time.perf_counter()
            path = write(folder / name, kind, d, tf)
            wrote = time.perf_counter() - t0
            times = []
            for _ in range(a.repeats):
                dt, imu, mocap = read(path, tf)
                times.append(dt)
            check(imu, mocap, d, tf)
            best[kind, tf] = min(times)
            sizes.setdefault(kind, []).append(path.stat().st_size / 1e6)
            label = f"{'ROS 1 bag' if kind == 'rosbag1' else 'MCAP'}{' (/tf)' if tf else ''}"
            print(f"{label:16s} {path.stat().st_size / 1e6:7.1f} MB  written in {wrote:5.1f} s"
                  f"  read: best {min(times):5.2f} s, median {float(np.median(times)):5.2f} s "
                  f"over {a.repeats}  (values checked)")
    finally:
        if a.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    n = len(d["ti"]) + len(d["tm"])
    def size(kind: str) -> str:
        lo, hi = f"{min(sizes[kind]):.0f}", f"{max(sizes[kind]):.0f}"
        return f"{lo} MB" if lo == hi else f"{lo}-{hi} MB"

    rows = [[f"{'ROS 1 bag' if kind == 'rosbag1' else 'MCAP'} ({size(kind)})",
             f"{best[kind, False]:.1f} s", *([f"{best[kind, True]:.1f} s"] if a.tf else [])]
            for kind in ("rosbag1", "mcap")]
    count = f"{n:,}".replace(",", " ")
    text = (doc.provenance("bench_bags.py") + "\n"
            + doc.table([f"{a.minutes:g} min, {count} messages",
                     f"`PoseStamped`, best of {a.repeats}",
                     *(["`/tf` + `/tf_static` chain"] if a.tf else [])], rows))
    print(text)
    doc.write(a, {"bench_bags": text})


if __name__ == "__main__":
    main()
