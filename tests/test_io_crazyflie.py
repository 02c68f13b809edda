"""Crazyflie uSD event logs, read as recorded: the three real UTIL flights decode (checked
against figures from an independent ``struct`` walk of the files) and read through the loader;
damaged, truncated and unexpected logs get one line each. Synthetic logs are written here from
the layout Bitcraze documents (``tools/usdlog/cfusdlog.py``), independently of the reader."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from conftest import refused, shared_data
from usd_logs import ACCEL, BARO, GYRO, POSE, usd_bytes

from mocap_calib.core.model import so3
from mocap_calib.io.formats.crazyflie.usd_file import read_usd_log
from mocap_calib.io.loader import load_imu_file, load_inputs, sniff_format

FLIGHTS = ("cfBolt-log00", "0425-traj1", "0422-log00")
#: Records per event and the first gyro stamp (us), from a separate struct-by-struct walk.
COUNTS = {"cfBolt-log00": (51521, 51521, 15313, 320959510),
          "0425-traj1": (43380, 43380, 12552, 27634364),
          "0422-log00": (47378, 47378, 13724, 82011054)}

def flight(seconds: float = 3.0, seed: int = 0, pose: bool = True
           ) -> tuple[bytes, dict[str, np.ndarray]]:
    """A synthetic flight: gyro and accelerometer at 1 kHz on clocks 20 us apart, poses at
    250 Hz; values in the log's units (deg/s, g, m)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * 1000)
    tg = 5_000_000 + np.arange(n) * 1000  # us
    ta = tg + 20
    gyro = 20.0 * np.sin(np.outer(tg * 1e-6, [1.0, 1.3, 0.7])) + rng.normal(0, 0.1, (n, 3))
    acc = np.array([0.0, 0.0, 1.0]) + 0.1 * np.sin(np.outer(ta * 1e-6, [2.0, 1.5, 1.1]))
    m = int(seconds * 250)
    tp = 5_000_500 + np.arange(m) * 4000
    q = so3.rotmat_to_quat(so3.exp(0.3 * np.sin(np.outer(tp * 1e-6, [0.9, 0.5, 0.3]))))
    p = np.sin(np.outer(tp * 1e-6, [0.4, 0.6, 0.2]))
    recs = [(0, int(t), tuple(v)) for t, v in zip(tg, gyro, strict=True)]
    recs += [(1, int(t), tuple(v)) for t, v in zip(ta, acc, strict=True)]
    if pose:
        recs += [(2, int(t), (*pp, *qq[[1, 2, 3, 0]]))
                 for t, pp, qq in zip(tp, p, q, strict=True)]
    recs += [(3, int(t), (100.0,)) for t in tg[::10]]
    recs.sort(key=lambda r: r[1])
    data = usd_bytes([GYRO, ACCEL, POSE, BARO], recs)
    return data, {"tg": tg, "gyro": gyro, "ta": ta, "acc": acc, "tp": tp, "q": q, "p": p}


def put(tmp_path: Path, data: bytes, name: str = "log00") -> Path:
    path = tmp_path / name
    path.write_bytes(data)
    return path



# --- the real flights ------------------------------------------------------------------------

@pytest.mark.parametrize("name", FLIGHTS)
def test_real_flights_decode(name: str) -> None:
    path = shared_data("crazyflie_util", name)
    log = read_usd_log(path)
    n_gyro, n_acc, n_pose, first_us = COUNTS[name]
    assert log.version == 2
    assert (len(log.events["estGyroscope"]), len(log.events["estAcceleration"]),
            len(log.events["estPose"])) == (n_gyro, n_acc, n_pose)
    assert log.events["estGyroscope"].stamps_ns[0] == first_us * 1000
    for event in log.present():  # one clock: every event's stamps increase
        assert np.all(np.diff(event.stamps_ns) > 0), event.name
    pose = log.events["estPose"]
    q = np.stack([pose.values[f"locSrv.q{a}"] for a in "xyzw"], axis=1)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)
    acc = np.stack([log.events["estAcceleration"].values[f"acc.{a}"] for a in "xyz"], axis=1)
    assert 0.95 < np.median(np.linalg.norm(acc, axis=1)) < 1.1  # g
    assert "estTDOA" in log.listing() and "estFlow" in log.listing()


@pytest.mark.parametrize("name", FLIGHTS)
def test_real_flights_read_as_one_file(name: str) -> None:
    path = shared_data("crazyflie_util", name)
    assert sniff_format(path) == "crazyflie"
    imu, mocap, notes = load_inputs(path, path, None)
    n_gyro, _, n_pose, first_us = COUNTS[name]
    assert n_gyro - 2 <= len(imu) <= n_gyro and 990 < imu.rate_hz < 1030
    assert len(mocap) == n_pose and 270 < mocap.rate_hz < 310
    # One clock: the streams overlap for the whole flight.
    assert abs(imu.time_origin_ns - mocap.time_origin_ns) < 5_000_000
    assert 0.95 * 9.80665 < np.median(np.linalg.norm(imu.accel, axis=1)) < 1.1 * 9.80665
    assert any("interpolated linearly onto the gyro stamps" in x for x in notes)
    assert any("estPose" in x and "radio" in x for x in notes)


def test_real_flight_damaged_copies(tmp_path: Path) -> None:
    data = shared_data("crazyflie_util", "0425-traj1").read_bytes()
    cut = put(tmp_path, data[: len(data) // 2], "cut")
    refused(lambda: load_inputs(cut, cut, None), str(cut), "truncated", "copy the log")
    bad = bytearray(data)
    bad[data.index(b"gyro.x(f)") + 7] = ord("z")  # a variable's type is no type
    path = put(tmp_path, bytes(bad), "badtype")
    refused(lambda: load_inputs(path, path, None), str(path), "header is damaged", "gyro.x(z)")
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 0x10  # one bit inside an event's values
    path = put(tmp_path, bytes(flipped), "flipped")
    refused(lambda: load_inputs(path, path, None), str(path), "CRC-32", "damaged")
    empty = put(tmp_path, b"", "empty")
    refused(lambda: load_inputs(empty, empty, None), str(empty), "empty")


# --- synthetic logs --------------------------------------------------------------------------

def test_synthetic_flight_values_and_units(tmp_path: Path) -> None:
    data, truth = flight()
    path = put(tmp_path, data)
    imu, mocap, _ = load_inputs(path, path, None)
    # The accelerometer starts 20 us after the gyro: the first gyro sample has no
    # accelerometer sample before it and is left out, never extrapolated.
    tg = truth["tg"][1:]
    assert np.array_equal(imu.stamps_ns(), tg * 1000)
    np.testing.assert_allclose(imu.gyro, np.radians(truth["gyro"][1:].astype(np.float32)),
                               rtol=1e-6)
    # The accelerometer 20 us later, brought back onto the gyro stamps: within float32.
    want = np.array([0.0, 0.0, 1.0]) + 0.1 * np.sin(np.outer(tg * 1e-6, [2.0, 1.5, 1.1]))
    np.testing.assert_allclose(imu.accel / 9.80665, want, atol=2e-7)
    assert np.array_equal(mocap.stamps_ns(), truth["tp"] * 1000)
    np.testing.assert_allclose(mocap.position, truth["p"], atol=1e-6)
    dots = np.abs(np.sum(mocap.quat_wxyz * truth["q"], axis=1))
    assert np.all(dots > 1 - 1e-6)


def test_version_1_stamps_are_milliseconds(tmp_path: Path) -> None:
    recs = [(0, 1000 + k, (0.1, 0.2, 0.3)) for k in range(300)]
    recs += [(1, 1000 + k, (0.0, 0.0, 1.0)) for k in range(300)]
    path = put(tmp_path, usd_bytes([GYRO, ACCEL], sorted(recs, key=lambda r: r[1]), 1))
    imu, _ = load_imu_file(path)
    assert imu.time_origin_ns == 1000 * 1_000_000 and abs(imu.rate_hz - 1000.0) < 1e-6


def test_events_chosen_by_option(tmp_path: Path) -> None:
    data, _ = flight()
    path = put(tmp_path, data)
    line = refused(lambda: load_inputs(path, path, None, recording=_rec("stabilizer", None)),
                   str(path), "no event 'stabilizer'", "--imu-topic")
    assert all(f"{e} (" in line for e in ("estGyroscope", "estAcceleration", "estPose"))
    assert "gyro.x, gyro.y, gyro.z" in line
    refused(lambda: load_inputs(path, path, None, recording=_rec(None, "estBarometer")),
            "'estBarometer' has no pose fields", "baro.asl", "--mocap-topic")
    refused(lambda: load_imu_file(path, topic="estBarometer,estAcceleration"),
            "'estBarometer' has no x, y, z fields for the gyro", "baro.asl")
    imu, _ = load_imu_file(path, topic="estGyroscope,estAcceleration")
    assert len(imu) == 2999


def test_renamed_events_and_one_imu_event(tmp_path: Path) -> None:
    """A firmware variant's names: the defaults are refused with the events present; the
    option reads them, also one event holding both sensors."""
    n = 400
    both = ("imu", ("gyro.x(f)", "gyro.y(f)", "gyro.z(f)", "acc.x(f)", "acc.y(f)", "acc.z(f)"))
    recs = [(0, 1000 * (k + 1), (0.5, -0.2, 0.1, 0.01, 0.02, 0.99)) for k in range(n)]
    path = put(tmp_path, usd_bytes([both], recs))
    refused(lambda: load_imu_file(path), "no estGyroscope or estAcceleration events",
            "imu (gyro.x, gyro.y, gyro.z, acc.x, acc.y, acc.z; 400)", "--imu-topic")
    imu, _ = load_imu_file(path, topic="imu")
    np.testing.assert_allclose(imu.accel[0], np.float32([0.01, 0.02, 0.99]) * 9.80665)


def test_no_pose_events(tmp_path: Path) -> None:
    data, _ = flight(pose=False)
    path = put(tmp_path, data)
    imu, _ = load_imu_file(path)  # the IMU alone reads
    assert len(imu) == 2999
    refused(lambda: load_inputs(path, path, None), str(path), "no estPose events",
            "estGyroscope (", "--mocap-topic")


@pytest.mark.parametrize("cut", [1, 4, 7, 40, -1, -5, -13])
def test_truncated_synthetic_logs(tmp_path: Path, cut: int) -> None:
    data, _ = flight(seconds=1.0)
    path = put(tmp_path, data[:cut] if cut > 0 else data[:cut])
    msg = refused(lambda: load_inputs(path, path, None), str(path), "copy the log")
    assert any(w in msg for w in ("truncated", "cut short", "ends inside", "CRC")), msg


def test_damaged_headers(tmp_path: Path) -> None:
    data, _ = flight(seconds=1.0)
    v3 = put(tmp_path, data[:1] + struct.pack("<H", 3) + data[3:], "v3")
    refused(lambda: load_inputs(v3, v3, None), "version 3", "versions 1 and 2")
    # Too many event types: the definitions run into the events.
    many = put(tmp_path, data[:3] + struct.pack("<H", 60) + data[5:], "many")
    refused(lambda: load_inputs(many, many, None), str(many), "damaged", "copy the log")
    # An event id the header does not define.
    records = bytearray(data)
    at = data.index(b"baro.asl(f)\0") + len(b"baro.asl(f)\0")
    records[at:at + 2] = struct.pack("<H", 77)
    path = put(tmp_path, bytes(records), "id77")
    refused(lambda: load_inputs(path, path, None), "event id 77 is not defined", "ids 0, 1, 2, 3")


def test_zero_length_and_magic_alone(tmp_path: Path) -> None:
    empty = put(tmp_path, b"", "empty")
    refused(lambda: load_imu_file(empty), str(empty), "empty")
    one = put(tmp_path, b"\xbc", "one")
    refused(lambda: load_imu_file(one), str(one), "ends inside its header")


def _rec(imu_topic: str | None, mocap_topic: str | None):
    from mocap_calib.io.formats.bags import RecordingOptions

    return RecordingOptions(imu_topic, mocap_topic)
