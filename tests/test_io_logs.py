"""Drone logs as they are recorded: PX4 ULogs with several IMUs, raw sensor topics, gaps and
logger dropouts; ROS bags with dropped IMU messages and /tf chains; bulk reading.

Logs are written from the published formats (tests/recordings.py) with known values; expected
values come from those values (float32-rounded where PX4 stores float32), from scipy's
rotations (TF chains) or from pyulog reading the real logs directly.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from mocap_calib.cli.main import main
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.io.loader import load_imu_file, load_inputs

sys.path.insert(0, str(Path(__file__).parent))
from conftest import shared_data  # noqa: E402
from recordings import RawImuLog, write_bag, write_ulog  # noqa: E402

T0_US = 1_650_000_000_000_000
DEV = (0x25000A, 0x380022, 0x280022)  # PX4 device ids (bus type, bus, address, devtype)


def f32(a: np.ndarray) -> np.ndarray:
    return np.asarray(a).astype(np.float32).astype(np.float64)


def _streams(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Plausible gyro (rad/s) and accelerometer (m/s^2) readings, seeded."""
    rng = np.random.default_rng(seed)
    gyro = 0.3 * np.sin(np.linspace(0, 40, n))[:, None] + rng.normal(0, 0.01, (n, 3))
    accel = np.array([0.0, 0.0, -9.81]) + rng.normal(0, 0.05, (n, 3))
    return gyro, accel


def _one_line(capsys, code: int, expected: int = 2) -> str:
    err = capsys.readouterr().err
    assert code == expected, err
    lines = [x for x in err.strip().splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), err
    assert "Traceback" not in err
    return lines[0]


def _allan(path: Path, tmp_path: Path, *extra: str) -> int:
    return main(["allan", "--imu", str(path), *extra, "--out", str(tmp_path / "n.yaml"), "-q"])


# --- PX4 ULog: several IMUs, raw topics --------------------------------------------------------

def _three_imus(n: int = 2000, step_us: int = 2500) -> tuple[list[RawImuLog], list[tuple]]:
    """Three IMUs at 400 Hz; IMU k's accelerometer is instance (k+1)%3 (instance numbers of the
    two topics need not agree: the device id tells which belong together)."""
    logs, truth = [], []
    for k in range(3):
        t = T0_US + np.arange(n, dtype=np.int64) * step_us + 37 * k
        gyro, accel = _streams(n, seed=k)
        logs.append(RawImuLog(k, (k + 1) % 3, DEV[k], t, gyro, t, accel))
        truth.append((t, f32(gyro), f32(accel)))
    return logs, truth


def test_ulog_raw_imu_instances_are_read_by_device(tmp_path) -> None:
    logs, truth = _three_imus()
    ulg = write_ulog(tmp_path / "three.ulg", None, None, raw=tuple(logs))
    for topic, k in (("sensor_gyro:1", 1), ("sensor_accel:2", 1), ("sensor_gyro:0", 0),
                     ("sensor_gyro:2", 2), ("sensor_accel:0", 2)):
        imu, notes = load_imu_file(ulg, topic=topic)
        t, gyro, accel = truth[k]
        # Stamped with timestamp_sample (the writer publishes 200 us later, in timestamp).
        assert np.array_equal(imu.stamps_ns(), t * 1000), topic
        assert np.array_equal(imu.gyro, gyro) and np.array_equal(imu.accel, accel), topic
        assert not any("paired" in x for x in notes)


def test_ulog_raw_imu_pairs_by_instance_number_without_a_device_match(tmp_path) -> None:
    logs, truth = _three_imus(n=500)
    # Separate gyro and accelerometer chips (as on a Pixhawk 1): no device id matches.
    log = logs[1]
    odd = RawImuLog(1, 1, log.device_id, log.t_gyro_us, log.gyro, log.t_accel_us, log.accel,
                    0x123456)
    ulg = write_ulog(tmp_path / "sep.ulg", None, None, raw=(odd,))
    imu, notes = load_imu_file(ulg, topic="sensor_gyro:1")
    assert np.array_equal(imu.accel, truth[1][2])
    assert any("sensor_gyro:1 paired with sensor_accel:1 by instance number" in x for x in notes)


def test_ulog_sensor_combined_is_the_default_and_the_note_lists_the_imus(tmp_path) -> None:
    logs, _ = _three_imus(n=400)
    t = logs[0].t_gyro_us
    gyro, accel = _streams(len(t), seed=9)
    combined = ImuSamples((t - t[0]) * 1e-6, gyro, accel, int(t[0]) * 1000)
    ulg = write_ulog(tmp_path / "c.ulg", combined, None, raw=tuple(logs))
    imu, notes = load_imu_file(ulg)
    assert np.array_equal(imu.gyro, f32(gyro))
    note = next(x for x in notes if "sensor_combined" in x and "PX4 selected" in x)
    assert all(f"sensor_gyro:{k}" in note for k in range(3))


def test_ulog_accelerometer_on_its_own_stamps_is_interpolated_not_extrapolated(tmp_path) -> None:
    n = 4000  # 10 s of gyro at 400 Hz, accelerometer at 200 Hz, 1.25 ms later
    tg = T0_US + np.arange(n, dtype=np.int64) * 2500
    ta = T0_US + 1250 + np.arange(n // 2, dtype=np.int64) * 5000
    gap = (ta > T0_US + 4_000_000) & (ta < T0_US + 4_060_000)  # a 65 ms accelerometer gap
    ta = ta[~gap]
    gyro, _ = _streams(n, seed=3)
    # A linear accelerometer signal: linear interpolation must give it exactly (up to float32).
    c0, c1 = np.array([0.5, -0.3, -9.8]), np.array([0.02, -0.01, 0.03])
    accel = c0 + c1 * ((ta - T0_US) * 1e-6)[:, None]
    ulg = write_ulog(tmp_path / "rates.ulg", None, None,
                     raw=(RawImuLog(0, 0, DEV[0], tg, gyro, ta, accel),))
    imu, notes = load_imu_file(ulg, topic="sensor_gyro")
    left, right = ta[:-1][np.diff(ta) > 10_000][0], ta[1:][np.diff(ta) > 10_000][0]
    kept = (tg >= ta[0]) & (tg <= ta[-1]) & ~((tg > left) & (tg < right))
    assert np.array_equal(imu.stamps_ns(), tg[kept] * 1000)
    np.testing.assert_allclose(imu.accel, c0 + c1 * ((tg[kept] - T0_US) * 1e-6)[:, None],
                               rtol=0, atol=4e-6)
    assert np.array_equal(imu.gyro, f32(gyro)[kept])
    assert any("interpolated linearly onto the gyro stamps" in x
               and f"{int((~kept).sum())} gyro samples" in x for x in notes)


def test_ulog_bad_imu_choices_get_one_line(tmp_path, capsys) -> None:
    logs, _ = _three_imus(n=400)
    ulg = write_ulog(tmp_path / "raw.ulg", None, None, raw=tuple(logs))
    # Several IMUs, no sensor_combined and no --imu-topic: the line lists them.
    line = _one_line(capsys, _allan(ulg, tmp_path))
    assert "raw.ulg" in line and "3 instances of sensor_gyro" in line and "--imu-topic" in line
    assert all(f"sensor_gyro:{k}" in line and f"0x{DEV[k]:06X}" in line for k in range(3))
    # Unknown instance, unknown topic, a bag topic name.
    line = _one_line(capsys, _allan(ulg, tmp_path, "--imu-topic", "sensor_gyro:7"))
    assert "no instance 7 of sensor_gyro" in line and "sensor_gyro:2" in line
    for bad in ("sensor_gyroscope:1", "/imu0", "sensor_gyro:x"):
        line = _one_line(capsys, _allan(ulg, tmp_path, "--imu-topic", bad))
        assert f"'{bad}' is not an IMU topic" in line and "sensor_accel:0" in line, bad
    # sensor_combined asked for but not logged.
    line = _one_line(capsys, _allan(ulg, tmp_path, "--imu-topic", "sensor_combined"))
    assert "no sensor_combined data" in line and "sensor_gyro:1" in line


def test_ulog_imu_switch_is_refused(tmp_path, capsys) -> None:
    t = T0_US + np.arange(8000, dtype=np.int64) * 5000
    gyro, accel = _streams(len(t), seed=4)
    imu = ImuSamples((t - t[0]) * 1e-6, gyro, accel, int(t[0]) * 1000)
    sel = ((T0_US, DEV[0], DEV[0]), (T0_US + 20_000_000, DEV[1], DEV[0]))
    ulg = write_ulog(tmp_path / "switch.ulg", imu, None, selection=sel)
    line = _one_line(capsys, _allan(ulg, tmp_path))
    assert "switched its gyro" in line and f"0x{DEV[1]:06X}" in line and "20.000 s" in line
    assert "--imu-topic sensor_gyro:N" in line


# --- gaps and dropouts -------------------------------------------------------------------------

#: (start s, length s) of gaps like those of real PX4 logs (the logger start, buffer overruns),
#: on a 200 Hz stream: each leaves a step of 20-165 ms (a gap: over 3 steps of 5 ms), except
#: the 8 ms one (one sample lost: a 10 ms step, no gap).
PX4_GAPS = ((0.0, 0.161), (3.1, 0.008), (7.3, 0.036), (11.8, 0.065), (15.2, 0.024),
            (22.7, 0.032), (30.5, 0.018))
N_GAPS = 6


def _punch(imu: ImuSamples, gaps=PX4_GAPS) -> tuple[ImuSamples, int]:
    """Drop the samples strictly inside each gap; returns the stream and its number of gaps."""
    keep = np.ones(len(imu), bool)
    for t0, length in gaps:
        keep &= ~((imu.t > t0) & (imu.t < t0 + length))
    return imu.select(keep), N_GAPS


def _px4_sim(seed: int = 8) -> tuple[ImuSamples, MocapPoses]:
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    sim = simulate_flight(SimConfig(seed=seed, duration=40.0))
    ns = (sim.imu.stamps_ns() // 1000) * 1000
    imu = ImuSamples((ns - ns[0]) * 1e-9, sim.imu.gyro, sim.imu.accel, int(ns[0]))
    return imu, sim.mocap


def test_ulog_gaps_and_logger_dropouts_are_notes_not_refusals(tmp_path, capsys) -> None:
    imu, mocap = _px4_sim()
    gappy, n_gaps = _punch(imu)
    t0_us = int(gappy.stamps_ns()[0] // 1000)
    drops = ((t0_us + 11_800_000, 31), (t0_us + 22_700_000, 26))
    ulg = write_ulog(tmp_path / "px4.ulg", gappy, None, dropouts=drops)
    got, notes = load_imu_file(ulg)
    assert np.array_equal(got.stamps_ns(), gappy.stamps_ns())
    gap_note = next(x for x in notes if "gaps in the IMU stamps" in x)
    assert f"{n_gaps} gaps" in gap_note and "longest 0.16" in gap_note
    assert "at the logger start" in gap_note
    drop_note = next(x for x in notes if "dropouts" in x)
    assert "2 dropouts" in drop_note and "57 ms in all" in drop_note and "31 ms" in drop_note
    # No mocap topic: that is the refusal, reached although the IMU has gaps.
    line = _one_line(capsys, main(["calibrate", "--imu", str(ulg), "--mocap", str(ulg),
                                   "--out", str(tmp_path / "o.yaml"), "-q"]))
    assert "px4.ulg" in line and "vehicle_mocap_odometry" in line and "IMU gap" not in line


@pytest.mark.parametrize("kind,name", [("rosbag1", "drop.bag"), ("bare_mcap", "drop.mcap")])
def test_bag_with_dropped_imu_messages_reads(kind, name, tmp_path) -> None:
    imu, mocap = _px4_sim(seed=11)
    gappy, n_gaps = _punch(imu)
    bag = write_bag(tmp_path / name, kind, gappy, mocap)
    got, poses, notes = load_inputs(bag, bag, None)
    assert np.array_equal(got.stamps_ns(), gappy.stamps_ns())
    assert np.array_equal(got.gyro, gappy.gyro) and np.array_equal(got.accel, gappy.accel)
    assert np.array_equal(poses.position, mocap.position)
    assert any(f"{n_gaps} gaps in the IMU stamps" in x for x in notes)


# --- the real PX4 sample logs (no mocap topic logged) ------------------------------------------

@pytest.mark.parametrize("name", ["sample.ulg", "sample_log_small.ulg"])
@pytest.mark.parametrize("command", ["calibrate", "diagnose"])
def test_real_px4_logs_are_refused_only_for_the_missing_mocap_topic(name, command, tmp_path,
                                                                    capsys) -> None:
    ulg = shared_data("px4", name)
    line = _one_line(capsys, main([command, "--imu", str(ulg), "--mocap", str(ulg), "--out",
                                   str(tmp_path / "o.yaml"), "-q"]))
    assert name in line and "vehicle_mocap_odometry" in line and "vehicle_visual_odometry" in line
    assert "IMU gap" not in line


def test_real_px4_imu_arrives_whole_with_its_gaps_and_dropouts(tmp_path, capsys) -> None:
    from pyulog import ULog

    path = shared_data("px4", "sample.ulg")
    log = ULog(str(path))
    stamps = log.get_dataset("sensor_combined").data["timestamp"].astype(np.int64)
    d = np.diff(stamps)
    imu, notes = load_imu_file(path)
    assert np.array_equal(imu.stamps_ns(), stamps * 1000)
    # Steps over 3x the median (4 ms): 6 of 24-65 ms, and two of exactly 12 ms, which float
    # rounding of the seconds puts on either side of the limit.
    assert np.median(d) == 4000 and int(np.sum(d > 12_000)) == 6
    note = next(x for x in notes if "gaps in the IMU stamps" in x)
    n_gaps = int(note.split(": ")[1].split(" gaps")[0])
    assert int(np.sum(d > 12_000)) <= n_gaps <= int(np.sum(d >= 12_000)), note
    assert f"longest {d.max() * 1e-6:.3f} s" in note
    ms = [int(x.duration) for x in log.dropouts]
    assert any(f"{len(ms)} dropouts" in x and f"{sum(ms)} ms in all" in x for x in notes)
    # allan gets the whole IMU: it runs over the gaps or refuses in one line (the hover and
    # ground parts are not static), never for the reader's sake.
    code = _allan(path, tmp_path)
    err = capsys.readouterr().err
    if code != 0:
        lines = [x for x in err.strip().splitlines() if x.startswith("error:")]
        assert code in (2, 3) and len(lines) == 1 and "sample.ulg" in lines[0], err
        assert "cannot bridge" not in lines[0] and "Traceback" not in err


def test_real_log_with_three_imus_lists_them(tmp_path, capsys) -> None:
    path = shared_data("px4", "sample_log_small.ulg")
    line = _one_line(capsys, _allan(path, tmp_path, "--imu-topic", "sensor_gyro"))
    assert "3 instances of sensor_gyro" in line
    assert all(f"sensor_gyro:{k}" in line for k in range(3)) and "--imu-topic" in line
    line = _one_line(capsys, _allan(path, tmp_path, "--imu-topic", "sensor_accel:5"))
    assert "no instance 5 of sensor_accel" in line and "sensor_accel:2" in line


def test_cropping_is_not_blocked_by_gaps_outside_it(tmp_path, capsys) -> None:
    import yaml

    from mocap_calib.io.formats.euroc import write_mav0
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    sim = simulate_flight(SimConfig(seed=5, duration=40.0, effects={"time_offset": [0.004]}))
    imu = sim.imu.select(~((sim.imu.t > 33.0) & (sim.imu.t < 33.1)))
    root = write_mav0(tmp_path / "s", imu, sim.mocap)
    out = tmp_path / "c.yaml"
    # The whole session calibrates over the gap (bridged), and so does the part before it:
    # cropping comes before any gap rule (the cropped part has no gap to report).
    assert main(["calibrate", str(root), "--segments", "0", "--out", str(out), "-q"]) == 0
    assert yaml.safe_load(out.read_text())["imu_gaps"]["bridged"] == 1
    assert main(["calibrate", str(root), "--end", "30", "--segments", "0", "--out", str(out),
                 "-q"]) == 0
    res = yaml.safe_load(out.read_text())
    assert res["imu_gaps"]["count"] == 0
    assert abs(res["time_offset"] - 0.004) < 4 * res["sigma"]["time_offset"]
