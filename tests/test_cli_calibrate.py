"""`mocap-calib calibrate` end to end: the result file, the terminal table, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from mocap_calib.cli.main import main
from mocap_calib.workflows.simulate import simulate_to_folder


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("cal") / "s"
    simulate_to_folder(out, seed=21, duration=40.0, effects=["time_offset=0.005"])
    return out


def _one_line_error(code: int, err: str, code_expected: int = 2) -> None:
    assert code == code_expected, err
    lines = [x for x in err.strip().splitlines() if x.strip()]
    assert lines and lines[-1].startswith("error:"), err
    assert "Traceback" not in err


def test_calibrate_writes_the_conventions_keys(session: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "calib.yaml"
    rep = tmp_path / "calib.txt"
    assert main(["calibrate", str(session), "--out", str(out), "--report", str(rep), "-q"]) == 0
    stdout = capsys.readouterr().out
    assert "time_offset" in stdout and "position" in stdout
    assert "gyro_bias" in rep.read_text() and "chi2/dof" in rep.read_text()
    d = yaml.safe_load(out.read_text())
    truth = yaml.safe_load((session / "truth.yaml").read_text())
    for key in ("gyro_bias", "accel_bias", "gravity_in_mocap", "time_offset"):
        assert key in d
    assert set(d["T_marker_imu"]) == {"rotation_wxyz", "translation"}
    assert set(d["sigma"]) >= {"gyro_bias", "accel_bias", "rotation", "translation",
                               "gravity_in_mocap", "time_offset"}
    assert d["time_offset"] == pytest.approx(truth["time_offset"], abs=2e-4)
    assert np.linalg.norm(np.subtract(d["T_marker_imu"]["translation"],
                                      truth["T_marker_imu"]["translation"])) < 2e-3
    assert [s["name"] for s in d["stages"]] == ["attitude", "velocity", "position"]


def test_calibrate_with_two_files_and_an_effect(session: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "c.yaml"
    code = main(["calibrate", "--imu", str(session / "mav0/imu0/data.csv"), "--mocap",
                 str(session / "mav0/vicon0/data.csv"), "--out", str(out), "--model",
                 "base+time_offset+gravity_magnitude", "-q"])
    assert code == 0, capsys.readouterr().err
    d = yaml.safe_load(out.read_text())
    assert d["model"] == "base+time_offset+gravity_magnitude"
    assert d["effects"]["gravity_magnitude"]["gravity_magnitude"] == pytest.approx(9.81, abs=0.02)



@pytest.mark.slow  # two full calibrations through the command line
def test_noise_from_data_and_fixed_noise(tmp_path: Path, capsys) -> None:
    """A flight whose accelerometer is 10x noisier than its data sheet (the flying preset):
    by default the calibration uses the levels the data show, with --fixed-noise the given
    ones."""
    sess = tmp_path / "fly"
    assert main(["simulate", str(sess), "--preset", "flying", "--duration", "40",
                 "--seed", "3"]) == 0
    used = {}
    for flag in ("--noise-from-data", "--fixed-noise"):
        out = tmp_path / f"{flag}.yaml"
        code = main(["calibrate", str(sess), "--out", str(out), flag, "--segments", "0", "-q"])
        assert code == 0, capsys.readouterr().err
        used[flag] = yaml.safe_load(out.read_text())["noise"]["accelerometer_noise_density"]
    assert used["--fixed-noise"] == pytest.approx(2e-3)
    assert used["--noise-from-data"] > 5 * 2e-3, used


@pytest.mark.parametrize(("args", "named"), [
    ([], "give a mav0 folder, or both --imu and --mocap"),  # neither a folder nor files
    (["--imu", "nope.csv"], "1 --imu and 0 --mocap"),  # --mocap missing
    (["{session}", "--imu", "x.csv", "--mocap", "y.csv"], "mav0 folders or --imu/--mocap"),
    (["{tmp}/does_not_exist"], "{tmp}/does_not_exist: folder not found"),
    (["{session}", "--model", "base+warp_drive"], "--model: unknown effect 'warp_drive'"),
    (["{session}", "--gravity", "98.1"], "--gravity 98.1: must be between 5 and 15"),
    (["{session}", "--window", "0.001"], "--window 0.001: must be between 0.5 and 60"),
    (["{session}", "--noise", "{tmp}/missing_noise.yaml"],
     "{tmp}/missing_noise.yaml: noise file not found"),
    (["{session}", "--gyro-noise", "-1"], "--gyro-noise -1.0: must be above 0"),
    (["{session}", "--start", "30", "--end", "10"], "--end 10 must be after --start 30"),
    (["{session}", "--prior", "{tmp}/no_prior.yaml"],
     "{tmp}/no_prior.yaml: calibration result not found"),
])
def test_bad_input_is_one_line_exit_2(args: list[str], named: str, session: Path,
                                      tmp_path: Path, capsys) -> None:
    """One line, exit 2, naming the option or file at fault (and its value)."""
    argv = [a.format(session=session, tmp=tmp_path) for a in args]
    code = main(["calibrate", *argv, "--out", str(tmp_path / "o.yaml"), "-q"])
    err = capsys.readouterr().err
    _one_line_error(code, err)
    assert named.format(tmp=tmp_path) in err.strip().splitlines()[-1], err


def test_too_short_a_session_is_exit_3(tmp_path: Path, capsys) -> None:
    simulate_to_folder(tmp_path / "short", seed=3, duration=6.0)
    code = main(["calibrate", str(tmp_path / "short"), "--out", str(tmp_path / "o.yaml"), "-q"])
    _one_line_error(code, capsys.readouterr().err, 3)


def test_unwritable_output_fails_before_calibrating(session: Path, tmp_path: Path,
                                                     capsys) -> None:
    (tmp_path / "a_folder").mkdir()
    code = main(["calibrate", str(session), "--out", str(tmp_path / "a_folder"), "-q"])
    _one_line_error(code, capsys.readouterr().err)


def test_stalled_solve_exits_4_naming_the_stage(session: Path, tmp_path: Path, capsys) -> None:
    """With one LM iteration (and the one retry) a stage cannot finish: exit 4, no result.
    The clock starts 25 ms from the truth (the coarse search lands close enough for one)."""
    out = tmp_path / "c.yaml"
    code = main(["calibrate", str(session), "--out", str(out), "--max-iterations", "1",
                 "--time-offset", "0.03", "-q"])
    err = capsys.readouterr().err
    _one_line_error(code, err, 4)
    assert "did not converge" in err and "--max-iterations" in err
    assert not out.exists()


def test_run_lm_reports_whether_it_converged() -> None:
    """A curved problem (Rosenbrock) that LM cannot finish in 2 iterations, but can in 200."""
    import gtsam

    from mocap_calib.core.gtsam_tools import run_lm

    key = gtsam.symbol("x", 0)

    def err(this, v, H):  # residuals (1 - x, 10 (y - x^2))
        x, y = v.atVector(key)
        if H is not None:
            H[0] = np.array([[-1.0, 0.0], [-20.0 * x, 10.0]])
        return np.array([1.0 - x, 10.0 * (y - x * x)])

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2), [key], err))
    init = gtsam.Values()
    init.insert(key, np.array([-1.5, 2.0]))
    _, rep = run_lm(graph, init, max_iterations=2, retry=False)
    assert not rep.converged and rep.reason == "iteration limit"
    sol, rep = run_lm(graph, init, max_iterations=200)
    assert rep.converged
    np.testing.assert_allclose(sol.atVector(key), [1.0, 1.0], atol=1e-4)
