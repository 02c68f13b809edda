"""The format registry is the one place a format is known: a toy format defined here (a tiny
JSON-lines log holding both streams) is registered and read by every command with no other
change; options a format cannot use are refused or noted in one place."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from refusal_corpus import run_cli, session

from mocap_calib.io import registry
from mocap_calib.io.loader import load_imu_file, load_inputs, sniff_format
from mocap_calib.io.reading import Format, ReadOptions
from mocap_calib.io.streams import ImuTable, PoseTable
from mocap_calib.io.validate import Lines

MAGIC = b'{"toy":'


def _records(path: Path, key: str) -> list[dict]:
    return [r for r in map(json.loads, path.read_text().splitlines()) if key in r]


def _toy_imu(path: Path, opts: ReadOptions, notes: list[str]) -> ImuTable:
    rows = _records(path, "g")
    notes.append(f"{path}: toy IMU records")
    return ImuTable(np.array([r["t"] for r in rows], dtype=np.int64),
                    np.array([r["g"] for r in rows]), np.array([r["a"] for r in rows]),
                    Lines(f"{path} [toy]"))


def _toy_poses(path: Path, opts: ReadOptions, notes: list[str]) -> PoseTable:
    rows = _records(path, "q")
    return PoseTable(np.array([r["t"] for r in rows], dtype=np.int64),
                     np.array([r["q"] for r in rows]), np.array([r["p"] for r in rows]),
                     Lines(f"{path} [toy]"))


TOY = Format("toy", "toy JSON-lines log",
             lambda p: p.is_file() and p.open("rb").read(len(MAGIC)) == MAGIC,
             _toy_imu, _toy_poses, options=frozenset({"imu_topic"}))


@pytest.fixture
def toy() -> Iterator[Format]:
    registry.register(TOY)
    try:
        yield TOY
    finally:
        registry.unregister(TOY.key)


def write_toy(path: Path, duration: float = 20.0, seed: int = 5) -> Path:
    s = session(seed=seed, duration=duration)
    lines = [json.dumps({"toy": 1, "t": int(t), "g": g.tolist(), "a": a.tolist()})
             for t, g, a in zip(s.imu.stamps_ns(), s.imu.gyro, s.imu.accel, strict=True)]
    lines += [json.dumps({"toy": 1, "t": int(t), "q": q.tolist(), "p": p.tolist()})
              for t, q, p in zip(s.mocap.stamps_ns(), s.mocap.quat_wxyz, s.mocap.position,
                                 strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_toy_format_is_read_by_the_load_paths(toy: Format, tmp_path: Path) -> None:
    path = write_toy(tmp_path / "flight.toy", duration=5.0)
    assert sniff_format(path) == "toy"
    imu, mocap, notes = load_inputs(path, path, None)
    s = session(seed=5, duration=5.0)
    assert np.array_equal(imu.stamps_ns(), s.imu.stamps_ns())
    assert np.array_equal(mocap.position, s.mocap.position)
    assert any("toy JSON-lines log" in n for n in notes)
    imu2, notes2 = load_imu_file(path, topic="x")
    assert np.array_equal(imu2.gyro, imu.gyro) and any("toy IMU" in n for n in notes2)
    # An option the toy format does not take is noted (units) or refused (a column map).
    _, _, notes = load_inputs(path, path, None, gyro_unit="deg/s")
    assert f"ignored --gyro-unit for {path}: it is a toy JSON-lines log (SI units)" in notes
    with pytest.raises(Exception, match="--columns given, but this is a toy JSON-lines log"):
        load_imu_file(path, columns="t=0,gyro=1:4,accel=4:7")
    # Unregistered, the file is no format at all.
    registry.unregister("toy")
    with pytest.raises(Exception, match="no numeric data row"):
        load_imu_file(path)


@pytest.mark.slow
def test_toy_format_through_every_command(toy: Format, tmp_path: Path) -> None:
    path = write_toy(tmp_path / "flight.toy")
    calib = tmp_path / "calib.yaml"
    code, _, err, _ = run_cli(["calibrate", "--imu", str(path), "--mocap", str(path), "--out",
                               str(calib), "--segments", "0"])
    assert code == 0, err
    assert "toy JSON-lines log" in err
    code, _, err, _ = run_cli(["diagnose", "--imu", str(path), "--mocap", str(path), "--out",
                               str(tmp_path / "report.yaml"), "--max-steps", "1"])
    assert code in (0, 3), err
    assert "toy JSON-lines log" in err
    code, _, err, _ = run_cli(["groundtruth", "--imu", str(path), "--mocap", str(path),
                               "--calibration", str(calib), "--out", str(tmp_path / "gt.csv")])
    assert code == 0, err
    # The IMU-only commands read it; on 20 s of flight they refuse the data, not the format.
    for argv in (["allan", "--out", str(tmp_path / "noise.yaml")],
                 ["multipos", "--out", str(tmp_path / "intr.yaml")],
                 ["drift", "--calibration", str(calib), "--segment-start", "2",
                  "--segment-end", "12"],
                 ["drift", "--mocap", str(path), "--calibration", str(calib),
                  "--segment-start", "2", "--segment-end", "12"]):
        code, _, err, _ = run_cli([argv[0], "--imu", str(path), *argv[1:]])
        assert "IMU: 4001 samples" in err and "toy JSON-lines log" in err, (argv, err)
        assert code in (0, 2, 3), (argv, err)
        last = err.strip().splitlines()[-1].replace(str(tmp_path), "")
        assert not any(w in last for w in ("--columns", "format", "no numeric")), last
