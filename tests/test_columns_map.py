"""A ``--columns`` map is used or refused, never dropped: for EuRoC files, ROS bags, ULogs and
imu_tk pairs too, a malformed or wrong map must not run as if none had been given (a note is
not enough). The calibrate command's cases are in the refusal corpus
(``tests/refusal_more.py``); here the IMU-only commands and the recordings."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import shared_data
from refusal_corpus import clean

from mocap_calib.cli.main import main
from mocap_calib.io.formats.euroc import write_euroc_imu


def _refused(capsys: pytest.CaptureFixture[str], argv: list[str], *words: str) -> str:
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("error: ") and "Traceback" not in err
    for w in words:
        assert w in last, last
    return last


@pytest.fixture
def euroc_imu(tmp_path: Path) -> Path:
    return write_euroc_imu(tmp_path / "imu.csv", clean().imu)


def test_a_ulog_refuses_a_column_map(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    ulg = shared_data("px4", "sample_log_small.ulg")
    _refused(capsys, ["allan", "--imu", ulg, "--columns", "t=0,gyro=1:4,accel=4:7", "--out",
                      tmp_path / "a.yaml"], "--columns given", "PX4 ULog", "drop --columns")
    _refused(capsys, ["calibrate", "--imu", ulg, "--mocap", ulg, "--columns", "broad",
                      "--out", tmp_path / "c.yaml"], "--columns given", "drop --columns")


def test_imu_tk_files_refuse_a_column_map(capsys: pytest.CaptureFixture[str],
                                          tmp_path: Path) -> None:
    for name in ("acc.txt", "gyr.txt"):
        (tmp_path / name).write_text("0 0 0 0\n")
    _refused(capsys, ["multipos", "--accel", tmp_path / "acc.txt", "--gyro",
                      tmp_path / "gyr.txt", "--columns", "t=0,gyro=1:4,accel=4:7", "--out",
                      tmp_path / "m.yaml"], "--columns given with imu_tk", "drop --columns")


def test_a_euroc_imu_log_is_read_with_the_map(capsys: pytest.CaptureFixture[str],
                                              euroc_imu: Path, tmp_path: Path) -> None:
    """The map is used: one that swaps gyro and accel gets the swap named; one without IMU
    columns, or a malformed one, is refused."""
    out = ["--out", tmp_path / "a.yaml"]
    _refused(capsys, ["allan", "--imu", euroc_imu, "--columns", "t=0,gyro=4:7,accel=1:4", *out],
             "swapped")
    _refused(capsys, ["allan", "--imu", euroc_imu, "--columns", "t=0,quat=1:5,pos=5:8", *out],
             "--columns", "no IMU columns")
    _refused(capsys, ["multipos", "--imu", euroc_imu, "--columns", "accel=4:9", *out],
             "--columns", "accel= names 5 columns")
