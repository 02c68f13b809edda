"""``mocap-calib simulate``: the files it writes (read back here with plain csv/yaml, not the
project's readers), determinism to the byte, help, and one-line errors with exit code 2."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocap_calib.cli.main import main
from mocap_calib.core.model.effects import CANONICAL_EFFECTS
from mocap_calib.sim.flight import SIM_FAULTS, SimConfig, simulate_flight

ENTRY_POINT = Path(sys.executable).parent / "mocap-calib"
ORIGIN_NS = 1_600_000_000_000_000_000
IMU_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
POSE_HEADER = ("#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], "
               "q_RS_x [], q_RS_y [], q_RS_z []")


def read_table(path: Path) -> tuple[str, np.ndarray, np.ndarray]:
    """Header line, integer ns stamps (exact: no float64 detour), float columns."""
    with open(path, newline="") as f:
        header = f.readline().rstrip("\n")
        rows = list(csv.reader(f))
    stamps = np.array([int(r[0]) for r in rows], dtype=np.int64)
    values = np.array([[float(x) for x in r[1:]] for r in rows])
    return header, stamps, values


def run_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def run_entry_point(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "COLUMNS": "200"}
    env.pop("MOCAP_CALIB_DEBUG", None)
    return subprocess.run([str(ENTRY_POINT), *args], capture_output=True, text=True, cwd=cwd,
                          timeout=300, env=env)


@pytest.mark.slow
@pytest.mark.skipif(not ENTRY_POINT.exists(), reason="mocap-calib entry point not installed")
def test_acceptance_simulate_seed_7_time_offset(tmp_path: Path) -> None:
    proc = run_entry_point(["simulate", "OUT", "--seed", "7", "--effect", "time_offset=0.012"],
                           tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stdout + proc.stderr
    out = tmp_path / "OUT"
    imu_path = out / "mav0" / "imu0" / "data.csv"
    pose_path = out / "mav0" / "vicon0" / "data.csv"
    truth_path = out / "truth.yaml"
    for p in (imu_path, pose_path, truth_path):
        assert p.is_file(), p

    sim = simulate_flight(SimConfig(seed=7, effects={"time_offset": [0.012]}))
    header, stamps, values = read_table(imu_path)
    assert header == IMU_HEADER
    n = 90 * 200 + 1
    np.testing.assert_array_equal(stamps, ORIGIN_NS + np.arange(n, dtype=np.int64) * 5_000_000)
    assert values.shape == (n, 6)
    np.testing.assert_allclose(values[:, :3], sim.imu.gyro, rtol=1e-15, atol=0)
    np.testing.assert_allclose(values[:, 3:], sim.imu.accel, rtol=1e-15, atol=0)

    header, stamps, values = read_table(pose_path)
    assert header == POSE_HEADER
    np.testing.assert_array_equal(stamps, ORIGIN_NS + np.arange(90 * 100 + 1) * 10_000_000)
    np.testing.assert_allclose(values[:, :3], sim.mocap.position, rtol=1e-15, atol=0)
    q = values[:, 3:]
    assert np.all(q[:, 0] >= 0)
    q_mem = np.where(sim.mocap.quat_wxyz[:, :1] < 0, -sim.mocap.quat_wxyz, sim.mocap.quat_wxyz)
    np.testing.assert_allclose(q, q_mem, rtol=1e-15, atol=1e-300)

    truth = yaml.safe_load(truth_path.read_text())
    for key in ("gyro_bias", "accel_bias", "T_marker_imu", "gravity_in_mocap", "time_offset",
                "sigma"):
        assert key in truth, key
    assert set(truth["T_marker_imu"]) >= {"rotation_wxyz", "translation"}
    assert set(truth["sigma"]) >= {"gyro_bias", "accel_bias", "rotation", "translation",
                                   "gravity_in_mocap", "time_offset"}
    assert len(truth["gyro_bias"]) == len(truth["accel_bias"]) == 3
    assert len(truth["T_marker_imu"]["rotation_wxyz"]) == 4
    assert truth["T_marker_imu"]["rotation_wxyz"][0] >= 0
    assert np.linalg.norm(truth["gravity_in_mocap"]) == pytest.approx(1.0, abs=1e-12)
    assert len(truth["sigma"]["gravity_in_mocap"]) == 2
    assert truth["time_offset"] == 0.012
    # The file holds the in-memory truth (floats survive the YAML round trip).
    assert truth["gyro_bias"] == sim.truth["gyro_bias"]
    assert truth["T_marker_imu"] == sim.truth["T_marker_imu"]
    assert truth["gravity_in_mocap"] == sim.truth["gravity_in_mocap"]
    # It reports what was written.
    assert "wrote" in proc.stdout and "truth.yaml" in proc.stdout


@pytest.mark.skipif(not ENTRY_POINT.exists(), reason="mocap-calib entry point not installed")
def test_entry_point_help_exits_zero(tmp_path: Path) -> None:
    proc = run_entry_point(["simulate", "--help"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    for name in (*CANONICAL_EFFECTS, *SIM_FAULTS):
        assert name in proc.stdout, name


def test_help_mentions_every_effect(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(["simulate", "--help"], capsys)
    assert code == 0
    for name in (*CANONICAL_EFFECTS, *SIM_FAULTS):
        assert name in out, name
    assert "--seed" in out and "--effect" in out and "--protocol" in out


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_same_arguments_give_byte_identical_files(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    args = ["--seed", "3", "--duration", "6", "--effect", "time_offset=0.01", "--effect",
            "gyro_scale_misalignment", "-e", "mocap_outliers=2", "-e", "mocap_dropouts=1"]
    assert run_cli(["simulate", str(tmp_path / "a"), *args], capsys)[0] == 0
    assert run_cli(["simulate", str(tmp_path / "b"), *args], capsys)[0] == 0
    a, b = _files(tmp_path / "a"), _files(tmp_path / "b")
    assert set(a) == {"truth.yaml", "mav0/imu0/data.csv", "mav0/vicon0/data.csv"}
    assert a == b
    args[1] = "4"
    assert run_cli(["simulate", str(tmp_path / "c"), *args], capsys)[0] == 0
    c = _files(tmp_path / "c")
    assert all(c[k] != a[k] for k in a)


def test_effect_values_reach_the_truth(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    g = [0.01, 0.0, 0.0, 0.0, -0.02, 0.0, 0.0, 0.0, 0.005]
    code, _, err = run_cli(["simulate", str(tmp_path / "o"), "--duration", "3", "--effect",
                            "gyro_scale_misalignment=" + ",".join(map(str, g)),
                            "--effect", "gravity_magnitude=9.79"], capsys)
    assert code == 0, err
    truth = yaml.safe_load((tmp_path / "o" / "truth.yaml").read_text())
    np.testing.assert_allclose(truth["effects"]["gyro_scale_misalignment"]["gyro_matrix"],
                               np.eye(3) + np.reshape(g, (3, 3)), rtol=0, atol=1e-15)
    assert truth["gravity_magnitude"] == 9.79
    assert truth["time_offset"] == 0.0


def test_max_motion_hz_reaches_the_session(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """--max-motion-hz 5 puts motion up to 5 Hz into the written IMU file (the default
    flight has next to none above 1.5 Hz) and records it in the truth."""
    spectra = []
    for name, extra in (("slow", []), ("fast", ["--max-motion-hz", "5"])):
        code, _, err = run_cli(["simulate", str(tmp_path / name), "--duration", "30", "--seed",
                                "4", *extra], capsys)
        assert code == 0, err
        _, _, cols = read_table(tmp_path / name / "mav0" / "imu0" / "data.csv")
        gyro = cols[:, 0:3] - cols[:, 0:3].mean(axis=0)
        power = np.abs(np.fft.rfft(gyro, axis=0)) ** 2
        f = np.fft.rfftfreq(len(gyro), 1 / 200.0)
        spectra.append(power[(f > 2.0) & (f < 5.0)].sum())
    assert spectra[1] > 20 * spectra[0], spectra
    truth = yaml.safe_load((tmp_path / "fast" / "truth.yaml").read_text())
    assert truth["simulation"]["max_motion_hz"] == 5.0


def test_protocol_multipos_writes_imu_and_truth(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "mp"
    code, stdout, err = run_cli(["simulate", str(out), "--protocol", "multipos", "--seed", "2"],
                                capsys)
    assert code == 0, err
    header, stamps, values = read_table(out / "mav0" / "imu0" / "data.csv")
    assert header == IMU_HEADER
    np.testing.assert_array_equal(np.diff(stamps), 5_000_000)
    assert stamps[0] == ORIGIN_NS and values.shape[1] == 6
    assert not (out / "mav0" / "vicon0").exists()
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    M_a = np.asarray(truth["accel_matrix"])
    assert M_a.shape == (3, 3) and np.all(np.triu(M_a, 1) == 0)
    assert np.asarray(truth["gyro_matrix"]).shape == (3, 3)
    assert len(truth["accel_bias"]) == len(truth["gyro_bias"]) == 3
    # Static at the start: |accel| ~ |g| (scale errors < 1 %, biases < 0.2 m/s^2).
    first = values[:200, 3:]
    assert np.linalg.norm(first, axis=1).mean() == pytest.approx(9.81, rel=0.03)


def test_protocol_static_writes_imu_and_truth(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "st"
    code, _, err = run_cli(["simulate", str(out), "--protocol", "static", "--duration", "5",
                            "--imu-rate", "100"], capsys)
    assert code == 0, err
    header, stamps, values = read_table(out / "mav0" / "imu0" / "data.csv")
    assert header == IMU_HEADER
    np.testing.assert_array_equal(stamps, ORIGIN_NS + np.arange(501) * 10_000_000)
    assert np.linalg.norm(values[:, 3:].mean(axis=0)) == pytest.approx(9.81, abs=0.4)
    assert np.abs(values[:, :3].mean(axis=0)).max() < 0.03  # rad/s: still, bias only
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    assert truth["gyroscope_noise_density"] > 0 and truth["accelerometer_random_walk"] > 0


def _assert_one_line_error(code: int, out: str, err: str, *fragments: str) -> None:
    assert code == 2, (code, out, err)
    assert "Traceback" not in out + err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("error:"), err
    for frag in fragments:
        assert frag in lines[0], (frag, err)


@pytest.mark.parametrize("args,fragments", [
    (["--effect", "bogus"], ["bogus", "time_offset"]),
    (["--effect", "time_offset=abc"], ["time_offset=abc"]),
    (["--effect", "time_offset=nan"], ["finite"]),
    (["--duration", "-5"], ["--duration"]),
    (["--duration", "0.5"], ["--duration"]),
    (["--imu-rate", "0"], ["--imu-rate"]),
    (["--mocap-rate", "400"], ["--mocap-rate"]),
    (["--protocol", "wobble"], ["wobble", "flight"]),
    (["--protocol", "static", "--effect", "time_offset=0.01"], ["flight"]),
    (["--effect", "gravity_magnitude=98.1"], ["gravity_magnitude"]),
    (["--max-motion-hz", "50"], ["--max-motion-hz", "20"]),
    (["--protocol", "static", "--max-motion-hz", "5"], ["--max-motion-hz", "flight"]),
])
def test_bad_options_give_one_line_error_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                args: list[str], fragments: list[str]) -> None:
    code, out, err = run_cli(["simulate", str(tmp_path / "o"), "--duration", "3", *args]
                             if "--duration" not in args
                             else ["simulate", str(tmp_path / "o"), *args], capsys)
    _assert_one_line_error(code, out, err, *fragments)
    assert not (tmp_path / "o" / "truth.yaml").exists()


def test_out_dir_is_an_existing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "taken"
    target.write_text("precious")
    code, out, err = run_cli(["simulate", str(target), "--duration", "3"], capsys)
    _assert_one_line_error(code, out, err, str(target))
    assert target.read_text() == "precious"


@pytest.mark.parametrize("args", [["simulate"], ["simulate", "o", "--bogus"],
                                  ["simulate", "o", "--seed", "abc"]])
def test_usage_errors_exit_2_without_traceback(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str],
                                               monkeypatch: pytest.MonkeyPatch,
                                               args: list[str]) -> None:
    monkeypatch.chdir(tmp_path)
    code, out, err = run_cli(args, capsys)
    assert code == 2
    assert "Traceback" not in out + err
    assert err.strip()


def test_unexpected_exception_is_internal_error_70(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str],
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    import mocap_calib.cli.commands.simulate as cmd

    def boom(*args: object, **kwargs: object) -> None:
        raise RuntimeError("simulated bug")

    monkeypatch.setattr(cmd, "simulate_request", boom)
    monkeypatch.delenv("MOCAP_CALIB_DEBUG", raising=False)
    code, out, err = run_cli(["simulate", str(tmp_path / "o")], capsys)
    assert code == 70
    assert "internal error" in err and "simulated bug" in err
    assert "Traceback" not in out + err
