"""Inputs that used to be refused for the wrong reason get a line naming the cause: a gzip'd
CSV, a pipe, an IMU clock that resets mid-log, mocap at 2 Hz, a ULog with junk appended. The
crop comes before the checks: rows cropped away are never refused. Per-file column maps, TUM
files with extra columns, and options a format does not use."""

from __future__ import annotations

import gzip
import os
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import refused, shared_data
from recordings import write_ulog
from refusal_corpus import clean, run_cli

from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.io.formats.euroc import write_euroc_imu, write_euroc_poses, write_mav0
from mocap_calib.io.formats.tum import write_tum
from mocap_calib.io.loader import load_imu_file, load_inputs
from mocap_calib.io.streams import Crop


def cli_refusal(argv: list, *parts: str, code: int = 2) -> str:
    got, _, err, _ = run_cli([str(a) for a in argv])
    last = err.strip().splitlines()[-1]
    assert got == code and last.startswith("error: ") and "Traceback" not in err, err
    for part in parts:
        assert part in last, f"{part!r} not in {last!r}"
    return last


# --- the cause named -------------------------------------------------------------------------

def test_gzip_csv_is_named(tmp_path: Path) -> None:
    csv = write_euroc_imu(tmp_path / "imu.csv", clean().imu)
    gz = tmp_path / "imu.csv.gz"
    gz.write_bytes(gzip.compress(csv.read_bytes()))
    refused(lambda: load_imu_file(gz), str(gz), "gzip-compressed", "gunzip")
    poses = write_euroc_poses(tmp_path / "poses.csv", clean().mocap)
    cli_refusal(["calibrate", "--imu", gz, "--mocap", poses, "--out", tmp_path / "c.yaml"],
                "gzip-compressed", "decompress it first")


def test_pipe_is_named(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)  # what <(zcat imu.csv.gz) hands over, without a writer
    refused(lambda: load_imu_file(fifo), str(fifo), "not a regular file", "pipe",
            "write it to a file first")
    refused(lambda: load_inputs(fifo, fifo, None), "not a regular file")


def _reset_imu(tmp_path: Path, back_s: float = 10.0, at: int = 3000) -> tuple[Path, ImuSamples]:
    """The clean IMU log whose clock jumps back by ``back_s`` at data row ``at`` (15 s)."""
    imu = clean().imu
    t = imu.t.copy()
    t[at:] -= back_s
    return write_euroc_imu(tmp_path / "imu.csv", ImuSamples(t, imu.gyro, imu.accel,
                                                             imu.time_origin_ns)), imu


def test_imu_clock_reset_is_named_with_its_line_and_the_crop(tmp_path: Path) -> None:
    path, imu = _reset_imu(tmp_path)
    msg = refused(lambda: load_imu_file(path), str(path), "line 3002", "clock resets",
                  "back by 9.995 s", "from 14.995 s to 5.000 s", "split the file",
                  "--end", "--start")
    assert "sort the file" not in msg
    # Either crop it names reads one stretch, and the checks run on that stretch only.
    end = float(re.search(r"--end (\S+)", msg).group(1))
    start = float(re.search(r"--start (\S+)", msg).group(1))
    first, _ = load_imu_file(path, crop=Crop(end=end))
    assert first.t[-1] < 5.0 and np.all(np.diff(first.t) > 0)
    second, _ = load_imu_file(path, crop=Crop(start=start))
    assert second.t[0] > 14.995 and np.all(np.diff(second.t) > 0)
    # Rows out of order (a swap) are still "not sorted".
    lines = write_euroc_imu(tmp_path / "ok.csv", imu).read_text().splitlines()
    lines[100], lines[101] = lines[101], lines[100]
    (tmp_path / "swap.csv").write_text("\n".join(lines) + "\n")
    refused(lambda: load_imu_file(tmp_path / "swap.csv"), "not sorted", "sort the file")


def test_mocap_at_2_hz_names_the_rate_and_the_minimum(tmp_path: Path) -> None:
    s = clean()
    slow = s.mocap.select(np.arange(len(s.mocap)) % 50 == 0)  # 100 Hz -> 2 Hz
    root = write_mav0(tmp_path / "s", s.imu, slow)
    cli_refusal(["calibrate", root, "--out", tmp_path / "c.yaml"], "2 Hz", "500 ms",
                "at least 10 Hz", "higher rate")


def test_ulog_with_junk_appended_is_read_up_to_it(tmp_path: Path) -> None:
    s = clean()
    ulg = write_ulog(tmp_path / "log.ulg", s.imu.select(s.imu.t < 10.0), None)
    whole, _ = load_imu_file(ulg)
    junk = tmp_path / "junk.ulg"
    junk.write_bytes(ulg.read_bytes() + bytes(4096))  # a copy padded to the card's block
    imu, notes = load_imu_file(junk)
    assert np.array_equal(imu.gyro, whole.gyro)
    assert any("4096 trailing bytes after the last complete message" in n for n in notes)
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(ulg.read_bytes()[:-7])
    refused(lambda: load_imu_file(cut), "ends inside a message", "truncated")


def test_real_ulog_with_junk_appended(tmp_path: Path) -> None:
    data = shared_data("px4", "sample.ulg").read_bytes()
    junk = tmp_path / "sample.ulg"
    junk.write_bytes(data + np.random.default_rng(4).bytes(3000))
    imu, notes = load_imu_file(junk)
    assert len(imu) == 17070 and any("3000 trailing bytes" in n for n in notes)


# --- crop before checks ----------------------------------------------------------------------

def test_rows_cropped_away_are_never_refused(tmp_path: Path) -> None:
    s = clean()
    lines = write_euroc_imu(tmp_path / "imu.csv", s.imu).read_text().splitlines()
    k = int(np.searchsorted(s.imu.t, 25.0)) + 1
    lines[k] = lines[k].rsplit(",", 1)[0] + ",nan"  # a bad IMU row at 25 s
    bad_imu = tmp_path / "bad_imu.csv"
    bad_imu.write_text("\n".join(lines) + "\n")
    poses = s.mocap
    q = poses.quat_wxyz.copy()
    q[int(np.searchsorted(poses.t, 27.0))] *= 1.5  # a bad quaternion at 27 s
    bad_pose = write_euroc_poses(tmp_path / "poses.csv", MocapPoses(
        poses.t, q, poses.position, poses.time_origin_ns))
    refused(lambda: load_inputs(bad_imu, bad_pose, None), "NaN")
    refused(lambda: load_imu_file(bad_imu), "NaN")
    imu, mocap, _ = load_inputs(bad_imu, bad_pose, None, crop=Crop(2.0, 20.0))
    # The streams keep the whole log's origin: times read as those of the uncropped log.
    assert imu.time_origin_ns == s.imu.time_origin_ns and abs(imu.t[0] - 2.0) < 0.01
    assert mocap.t[0] >= 1.0 - 1e-9 and mocap.t[-1] <= 21.0 + 1e-9
    cropped, _ = load_imu_file(bad_imu, crop=Crop(None, 20.0))
    assert np.array_equal(cropped.gyro, s.imu.gyro[s.imu.t <= 20.0])
    # The bad rows inside the crop are refused, naming the file's line.
    refused(lambda: load_inputs(bad_imu, bad_pose, None, crop=Crop(20.0, None)),
            f"line {k + 1}", "NaN")


def test_crop_keeps_the_numbers_of_the_old_cut(tmp_path: Path) -> None:
    """Cropping the tables gives the samples the cut of the checked streams gave."""
    from mocap_calib.core.prepare.crop import crop_session

    s = clean()
    root = write_mav0(tmp_path / "s", s.imu, s.mocap)
    whole_imu, whole_mocap, _ = load_inputs(None, None, root)
    for start, end, offset in ((3.0, 17.5, None), (None, 12.0, 0.02), (8.0, None, -0.3)):
        imu, mocap, _ = load_inputs(None, None, root, crop=Crop(start, end,
                                                             1.0 + abs(offset or 0.0)))
        old_imu, old_mocap = crop_session(whole_imu, whole_mocap, start, end, offset)
        assert np.array_equal(imu.t, old_imu.t) and np.array_equal(imu.gyro, old_imu.gyro)
        assert imu.time_origin_ns == old_imu.time_origin_ns
        assert np.array_equal(mocap.t, old_mocap.t)
        assert np.array_equal(mocap.quat_wxyz, old_mocap.quat_wxyz)


# --- column maps per file, TUM with extra columns, unused options -------------------------------

def _layouts(tmp_path: Path) -> tuple[Path, Path]:
    """An IMU CSV (accel before gyro, ms stamps... in s) and a ;-separated pose file of
    another layout."""
    s = clean()
    i, m = s.imu, s.mocap
    imu = tmp_path / "imu.csv"
    imu.write_text("time,ax,ay,az,gx,gy,gz\n" + "\n".join(
        f"{t:.9f},{a[0]!r},{a[1]!r},{a[2]!r},{g[0]!r},{g[1]!r},{g[2]!r}"
        for t, a, g in zip(i.stamps_ns() * 1e-9, i.accel.tolist(), i.gyro.tolist(),
                           strict=True)) + "\n")
    poses = tmp_path / "poses.csv"
    poses.write_text("stamp;x;y;z;qx;qy;qz;qw\n" + "\n".join(
        f"{t:.9f};{p[0]!r};{p[1]!r};{p[2]!r};{q[1]!r};{q[2]!r};{q[3]!r};{q[0]!r}"
        for t, p, q in zip(m.stamps_ns() * 1e-9, m.position.tolist(), m.quat_wxyz.tolist(),
                           strict=True)) + "\n")
    return imu, poses


def test_two_layouts_read_with_a_map_each(tmp_path: Path) -> None:
    imu_path, pose_path = _layouts(tmp_path)
    imu, mocap, notes = load_inputs(imu_path, pose_path, None,
                                    imu_columns="t=time,accel=1:4,gyro=gx|gy|gz",
                                    mocap_columns="t=0,pos=x|y|z,quat=4:8", quat_order="xyzw")
    s = clean()
    np.testing.assert_allclose(imu.gyro, s.imu.gyro, rtol=0, atol=0)
    np.testing.assert_allclose(mocap.quat_wxyz, s.mocap.quat_wxyz, atol=1e-15)
    # One map for both does not fit both files: the other file's names are not in it.
    refused(lambda: load_inputs(imu_path, pose_path, None,
                                columns="t=time,accel=1:4,gyro=4:7,pos=x|y|z,quat=4:8"),
            str(pose_path), "no column named 'time'")


@pytest.mark.parametrize("kw,parts", [
    ({"columns": "t=0,gyro=1:4,accel=4:7", "imu_columns": "t=0,gyro=1:4,accel=4:7"},
     ("--columns and --imu-columns both given", "not both")),
    ({"imu_columns": "t=0,gyro=1:4,accel=4:7,pos=7:10,quat=10:14"},
     ("--imu-columns", "no quat=/pos=", "--mocap-columns")),
    ({"mocap_columns": "t=0,gyro=1:4,accel=4:7"}, ("--mocap-columns", "quat= and pos=")),
    ({"imu_columns": "t=0,gyro=1:3,accel=4:7"}, ("--imu-columns", "gyro= names 2 columns")),
])
def test_conflicting_maps_are_refused_in_one_line(tmp_path: Path, kw: dict,
                                                   parts: tuple[str, ...]) -> None:
    imu_path, pose_path = _layouts(tmp_path)
    refused(lambda: load_inputs(imu_path, pose_path, None, **kw), *parts)


def test_per_file_maps_on_the_command_line(tmp_path: Path) -> None:
    imu_path, pose_path = _layouts(tmp_path)
    code, _, err, _ = run_cli(["calibrate", "--imu", str(imu_path), "--mocap", str(pose_path),
                               "--imu-columns", "t=0,accel=1:4,gyro=4:7", "--mocap-columns",
                               "t=0,pos=1:4,quat=4:8", "--quat-order", "xyzw", "--segments",
                               "0", "--out", str(tmp_path / "c.yaml")])
    assert code == 0, err


def test_tum_with_extra_columns(tmp_path: Path) -> None:
    s = clean()
    tum = write_tum(tmp_path / "plain.txt", s.mocap).read_text().splitlines()
    rows = [ln + " 0.5 -0.25 1e-3 7" if not ln.startswith("#") else
            ln + " vx vy vz quality" for ln in tum]
    path = tmp_path / "traj.txt"
    path.write_text("\n".join(rows) + "\n")
    imu = write_euroc_imu(tmp_path / "imu.csv", s.imu)
    _, mocap, notes = load_inputs(imu, path, None)
    np.testing.assert_allclose(mocap.position, s.mocap.position, atol=0)
    assert any("read as a TUM trajectory" in n and "'vx', 'vy', 'vz', 'quality'" in n
               for n in notes)
    # Read through a map instead, the extra columns are there to name.
    _, mocap2, _ = load_inputs(imu, path, None, mocap_columns="t=0,pos=1:4,quat=4:8",
                               quat_order="xyzw")
    np.testing.assert_allclose(mocap2.quat_wxyz, mocap.quat_wxyz, atol=0)
    # Twelve columns without a unit quaternion in fields 5-8 are no TUM file.
    other = tmp_path / "other.txt"
    other.write_text("\n".join(" ".join(f"{k + c * 0.1:.3f}" for c in range(12))
                               for k in range(100)) + "\n")
    refused(lambda: load_inputs(imu, other, None), str(other), "--columns")


def test_options_a_format_does_not_use_are_noted(tmp_path: Path) -> None:
    s = clean()
    root = write_mav0(tmp_path / "s", s.imu, s.mocap)
    _, _, notes = load_inputs(None, None, root, recording=_rec("/imu", "/pose"))
    assert (f"ignored --imu-topic, --mocap-topic for {root}: a EuRoC mav0 folder does not use "
            "them") in notes
    imu = root / "imu0" / "data.csv"
    _, notes = load_imu_file(imu, topic="/imu0")
    assert f"ignored --imu-topic for {imu}: a EuRoC IMU CSV does not use it" in notes


def _rec(imu_topic: str | None, mocap_topic: str | None):
    from mocap_calib.io.reading import RecordingOptions

    return RecordingOptions(imu_topic, mocap_topic)


def test_a_shared_map_naming_one_stream_is_for_that_file(tmp_path: Path) -> None:
    """--columns naming only the IMU's columns reads the IMU file with it and leaves the pose
    file (TUM here) to its own format; a column map is still refused by a file that has no
    columns when it names that file's stream."""
    s = clean()
    imu = write_euroc_imu(tmp_path / "imu.csv", s.imu)
    tum = write_tum(tmp_path / "traj.txt", s.mocap)
    got, mocap, notes = load_inputs(imu, tum, None, columns="t=0,gyro=1:4,accel=4:7")
    assert len(mocap) == len(s.mocap) and any("with the --columns map" in n for n in notes)
    ulg = write_ulog(tmp_path / "log.ulg", s.imu, None)
    refused(lambda: load_inputs(ulg, tum, None, columns="t=0,gyro=1:4,accel=4:7"),
            "--columns given, but this is a PX4 ULog")
    refused(lambda: load_imu_file(ulg, columns="t=0,quat=1:5,pos=5:8"), "no IMU columns")
