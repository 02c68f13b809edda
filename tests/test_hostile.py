"""Careless and hostile inputs: every YAML input read by one reader that refuses what would
crash or mislead, priors and option files range-checked as their command-line flags are,
no export or result that holds NaN, and the crashes of hostile options turned into one line.
Each case gives one line naming the cause with a non-zero exit, or the right result."""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocap_calib.cli.main import main
from mocap_calib.core.model.parameters import (
    ACCEL_BIAS,
    GRAVITY_DIRECTION,
    GYRO_BIAS,
    ROTATION,
    TIME_OFFSET,
    TRANSLATION,
)
from mocap_calib.core.plausible import PlausibleLimits
from mocap_calib.core.result.priors import prior_problems
from mocap_calib.errors import ConvergenceError, InputError
from mocap_calib.io import atomic
from mocap_calib.io.yaml_io import load_result, load_yaml, save_result, save_yaml
from mocap_calib.workflows.simulate import simulate_to_folder


def _run(*args: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def _refused(code: int, err: str, *words: str) -> str:
    assert code == 2, err
    lines = err.strip().splitlines()
    assert lines and lines[-1].startswith("error: ") and "Traceback" not in err, err
    for w in words:
        assert w in lines[-1], lines[-1]
    return lines[-1]


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("hostile") / "s"
    simulate_to_folder(out, seed=3, duration=20.0)
    return out


@pytest.fixture(scope="module")
def result(session: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A result with sigmas (the simulator's truth plus plausible sigmas), as plain data."""
    r = load_result(session / "truth.yaml")
    sigmas = {ROTATION: np.full(3, 1e-3), TRANSLATION: np.full(3, 1e-3),
              GRAVITY_DIRECTION: np.full(2, 1e-3), GYRO_BIAS: np.full(3, 1e-4),
              ACCEL_BIAS: np.full(3, 1e-3), TIME_OFFSET: np.full(1, 1e-4)}
    r = r.with_estimates({p: replace(r.estimate(p), sigma=s) for p, s in sigmas.items()})
    r.session["imu_rate_hz"] = 200.0
    path = tmp_path_factory.mktemp("result") / "calib.yaml"
    save_result(path, r)
    return yaml.safe_load(path.read_text())


def _with(data: dict, tmp: Path, name: str = "calib.yaml", **changes: object) -> Path:
    """``data`` with ``changes`` (keys with dots go into mappings) written to ``tmp/name``."""
    d = yaml.safe_load(yaml.safe_dump(data))
    for key, value in changes.items():
        *parents, last = key.split(".")
        node = d
        for p in parents:
            node = node[p]
        node[last] = value
    path = tmp / name
    path.write_text(yaml.safe_dump(d))
    return path


# --- one YAML reader ----------------------------------------------------------------------

def _billion_laughs() -> str:
    lines = ['a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for k in range(1, 9):
        prev, name = chr(96 + k), chr(97 + k)
        lines.append(f"{name}: &{name} [" + ", ".join([f"*{prev}"] * 9) + "]")
    return "\n".join(lines) + "\nsessions:\n  - id: *i\n"


@pytest.mark.parametrize("text,words", [
    ("sessions:\n  - id: a\n    window: " + "1" * 4301 + "\n",
     ("line 3", "'sessions[0].window'", "4301 digits")),
    ("sessions:\n  - id: a\n    imu_id: b\n    date: 2024-02-30\n",
     ("line 4", "'sessions[0].date'", "2024-02-30 does not exist")),
    (_billion_laughs(), ("aliases", "expand to")),
    ("sessions: " + "[" * 5000 + "]" * 5000 + "\n", ("nested too deeply",)),
    ("sessions: [" + "[" * 70 + "]" * 70 + "]\n", ("nested more than 64",)),
    ("sessions: []\nsessions: []\n", ("line 2", "'sessions' is given twice",)),
])
def test_a_hostile_manifest_is_one_line(text: str, words: tuple[str, ...],
                                        tmp_path: Path) -> None:
    """Each of these crashed (ValueError, RecursionError: exit 70) or, for the aliases,
    printed hundreds of MB of error text before a MemoryError; a key given twice was kept
    silently."""
    manifest = tmp_path / "m.yaml"
    manifest.write_text(text)
    t0 = time.perf_counter()
    code, _, err = _run("batch", manifest, "--out", tmp_path / "out", "--quiet")
    line = _refused(code, err, str(manifest), *words)
    assert len(err) < 2000 and time.perf_counter() - t0 < 10.0, len(err)
    assert line


def test_a_yaml_file_over_the_size_limit_is_refused(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    from mocap_calib.io import yaml_io

    path = tmp_path / "noise.yaml"
    path.write_text("gyroscope_noise_density: 1.0e-4\n" + "# padding\n" * 1000)
    monkeypatch.setattr(yaml_io, "MAX_YAML_BYTES", 4096)
    with pytest.raises(InputError, match="MB, more than a noise file can be"):
        yaml_io.load_noise(path)


def test_exponents_without_a_dot_are_numbers_everywhere(tmp_path: Path, session: Path) -> None:
    """YAML 1.1 reads ``2e-4`` as a string; the noise file took it as a number, a manifest
    refused it ('must be a number'). Both read it as the number now, and a string that looks
    like one is quoted when written, so it reads back as a string."""
    from mocap_calib.batch.manifest import load_manifest

    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"sessions:\n  - {{id: a, imu_id: b, date: 2024-01-01, mav0: {session},"
                        " accel_noise: 2e-3, gyro_walk: 1E-5}\n")
    request = load_manifest(manifest).sessions[0].request
    assert (request.noise.accel_noise, request.noise.gyro_walk) == (2e-3, 1e-5)
    save_yaml(tmp_path / "x.yaml", {"text": "2e-4", "number": 2e-4, "hash": "1234e5678"})
    assert load_yaml(tmp_path / "x.yaml") == {"text": "2e-4", "number": 2e-4,
                                              "hash": "1234e5678"}


# --- option files within the options' ranges --------------------------------------------

@pytest.mark.parametrize("key,value,words", [
    ("gyroscope_noise_density", 1e30, ("at most 1 rad/s/sqrt(Hz)", "--gyro-noise")),
    ("accelerometer_random_walk", 50.0, ("at most 10 m/s^3/sqrt(Hz)", "--accel-walk")),
    ("mocap_position_sigma", 1.0, ("at most 0.1 m", "--mocap-noise-mm")),
])
def test_a_noise_file_is_held_to_the_flags_ranges(key: str, value: float, words: tuple[str, ...],
                                                  session: Path, tmp_path: Path) -> None:
    """Noise densities of 1e30 in a noise file were accepted while the flags have caps."""
    noise = tmp_path / "noise.yaml"
    noise.write_text(f"accelerometer_noise_density: 2.0e-3\n{key}: {value}\n")
    code, _, err = _run("calibrate", session, "--noise", noise, "--out", tmp_path / "c.yaml")
    _refused(code, err, str(noise), key, *words)
    assert not (tmp_path / "c.yaml").exists()


@pytest.mark.parametrize("text,words", [
    ("accel_bias: .nan\n", ("'accel_bias' is nan", "finite positive")),
    ("lever_arm: -1\n", ("'lever_arm' is -1",)),
    ("effects: {gyro_g_sensitivity: {max: .inf}}\n",
     ("'effects.gyro_g_sensitivity.max' is inf",)),
    ("effects: {gravity_magnitude: {min: 9.9, max: 9.7}}\n", ("min 9.9 not below max 9.7",)),
])
def test_plausibility_limits_must_be_finite_and_positive(text: str, words: tuple[str, ...],
                                                         session: Path, tmp_path: Path) -> None:
    """``accel_bias: .nan`` turned that check off without a word."""
    limits = tmp_path / "limits.yaml"
    limits.write_text(text)
    code, _, err = _run("calibrate", session, "--plausible", limits, "--out", tmp_path / "c.yaml")
    _refused(code, err, str(limits), *words)


# --- priors checked when they are read ------------------------------------------------------

@pytest.mark.parametrize("changes,words", [
    ({"T_marker_imu.translation": [1e308, 0.0, 0.0]},
     ("T_marker_imu.translation", "1e+308 m", "lever_arm")),
    ({"sigma.translation": [-1e-3, 1e-3, 1e-3]}, ("sigma.translation", "positive")),
    ({"sigma.rotation": [0.0, 1e-3, 1e-3]}, ("sigma.rotation", "positive")),
    ({"T_marker_imu.rotation_wxyz": [0.0, 0.0, 0.0, 0.0]},
     ("T_marker_imu.rotation_wxyz", "zero length")),
    ({"T_marker_imu.rotation_wxyz": [float("nan"), 0.0, 0.0, 1.0]},
     ("T_marker_imu.rotation_wxyz", "not finite")),
    ({"gravity_in_mocap": [0.0, 0.0, float("inf")]}, ("gravity_in_mocap", "not finite")),
])
def test_a_prior_that_cannot_be_one_is_refused(changes: dict, words: tuple[str, ...],
                                               result: dict, session: Path,
                                               tmp_path: Path) -> None:
    prior = _with(result, tmp_path, "prior.yaml", **changes)
    code, _, err = _run("calibrate", session, "--prior", prior, "--out", tmp_path / "c.yaml")
    _refused(code, err, str(prior), "as a --prior", *words)


def test_a_sound_prior_has_no_problems(result: dict) -> None:
    from mocap_calib.core.result.calibration import CalibrationResult

    assert prior_problems(CalibrationResult.from_dict(result), PlausibleLimits()) == []


# --- every export and result value finite ---------------------------------------------------

@pytest.mark.parametrize("target", ["basalt", "px4", "kalibr", "openvins"])
@pytest.mark.parametrize("changes,words", [
    ({"T_marker_imu.rotation_wxyz": [float("nan"), 0.0, 0.0, 0.0]},
     ("T_marker_imu.rotation_wxyz is [nan, 0.0, 0.0, 0.0]", "not a finite number")),
    ({"T_marker_imu.rotation_wxyz": [0.0, 0.0, 0.0, 0.0]},
     ("T_marker_imu.rotation_wxyz", "zero length")),
    ({"time_offset": float("inf")}, ("time_offset is inf",)),
    ({"noise.gyroscope_noise_density": float("nan")},
     ("noise.gyroscope_noise_density is nan",)),
])
def test_an_export_of_a_value_that_is_not_finite_is_refused(
        target: str, changes: dict, words: tuple[str, ...], result: dict,
        tmp_path: Path) -> None:
    """Basalt got ``"px": NaN`` (invalid JSON) and PX4 ``EKF2_EV_POS_X nan``."""
    calib = _with(result, tmp_path, **changes)
    out = tmp_path / "exported"
    code, _, err = _run("export", calib, "--to", target, "--out", out)
    _refused(code, err, str(calib), *words)
    assert not out.exists()


def test_a_sound_export_has_no_nan(result: dict, tmp_path: Path) -> None:
    import json

    calib = _with(result, tmp_path)
    code, _, err = _run("export", calib, "--to", "basalt", "--out", tmp_path / "b.json")
    assert code == 0, err
    json.loads((tmp_path / "b.json").read_text(), parse_constant=lambda c: pytest.fail(c))


def test_a_result_that_is_not_finite_is_not_written(result: dict, tmp_path: Path) -> None:
    from mocap_calib.core.result.calibration import CalibrationResult

    r = CalibrationResult.from_dict(result)

    def moved(value: np.ndarray) -> CalibrationResult:
        return r.with_estimates({TRANSLATION: replace(r.estimate(TRANSLATION), value=value)})

    with pytest.raises(ConvergenceError, match=r"T_marker_imu.translation\[0\] is nan"):
        save_result(tmp_path / "r.yaml", moved(np.array([np.nan, 0.0, 0.0])))
    r = replace(moved(np.zeros(3)),
                effects={"clock_drift": {"clock_drift": float("inf"), "sigma": 1e-6}})
    with pytest.raises(ConvergenceError, match="effects.clock_drift.clock_drift is inf"):
        save_result(tmp_path / "r.yaml", r)
    assert not (tmp_path / "r.yaml").exists()


def test_groundtruth_refuses_a_calibration_that_is_not_finite(result: dict, session: Path,
                                                              tmp_path: Path) -> None:
    calib = _with(result, tmp_path, **{"T_marker_imu.translation": [0.0, float("nan"), 0.0]})
    code, _, err = _run("groundtruth", session, "--calibration", calib, "--out",
                        tmp_path / "gt.csv")
    _refused(code, err, str(calib), "T_marker_imu.translation[1] is nan")


# --- hostile options ------------------------------------------------------------------------

def test_groundtruth_rate_is_bounded_by_the_imus(result: dict, session: Path,
                                                 tmp_path: Path) -> None:
    """``--rate 100000`` had no bound: 5.7 GB of memory for a minute of session."""
    calib = _with(result, tmp_path)
    code, _, err = _run("groundtruth", session, "--calibration", calib, "--rate", "100000",
                        "--out", tmp_path / "gt.csv")
    _refused(code, err, "--rate 100000 Hz", "IMU's own 200 Hz")
    code, _, err = _run("groundtruth", session, "--calibration", calib, "--rate", "1e9",
                        "--out", tmp_path / "gt.csv")
    _refused(code, err, "--rate")


@pytest.mark.parametrize("address", ["localhost", "tcp://localhost", "tcp://host:port"])
def test_a_scheduler_address_without_a_port_is_one_line(address: str, session: Path,
                                                        tmp_path: Path) -> None:
    pytest.importorskip("distributed")
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"sessions:\n  - {{id: a, imu_id: b, date: 2024-01-01, mav0: {session}}}\n")
    code, _, err = _run("batch", manifest, "--out", tmp_path / "out", "--engine", "dask",
                        "--scheduler", address, "--quiet")
    _refused(code, err, f"--scheduler {address}", "tcp://HOST:PORT")
    assert not (tmp_path / "out").exists()  # before any work


@pytest.mark.parametrize("ids,words", [
    (["batch.yaml"], ("the id 'batch.yaml' names the batch's own OUT/batch.yaml",)),
    (["fleet"], ("'fleet' names the batch's own",)),
    (["Drone1", "drone1"], ("duplicate id", "'Drone1'", "differ in case")),
    (["a/b"], ("invalid id 'a/b'",)),
    ([".."], ("invalid id '..'",)),
])
def test_a_session_id_that_is_no_folder_of_its_own_is_refused(
        ids: list[str], words: tuple[str, ...], session: Path, tmp_path: Path) -> None:
    """``id: batch.yaml`` crashed (NotADirectoryError, exit 70) after the first status
    write."""
    manifest = tmp_path / "m.yaml"
    manifest.write_text("sessions:\n" + "".join(
        f"  - {{id: '{i}', imu_id: b, date: 2024-01-01, mav0: {session}}}\n" for i in ids))
    code, _, err = _run("batch", manifest, "--out", tmp_path / "out", "--quiet")
    _refused(code, err, *words)
    assert not (tmp_path / "out").exists()


def test_a_file_name_that_is_not_utf8_is_written_escaped(tmp_path: Path) -> None:
    """Python reads such bytes of a name as lone surrogates, which UTF-8 cannot encode: the
    HTML report of an input named so ended in UnicodeEncodeError (exit 70)."""
    name = os.fsdecode(b"imu\xff.csv")
    atomic.write_text(tmp_path / "page.html", f"<p>{name}</p>\n")
    assert (tmp_path / "page.html").read_text(encoding="utf-8") == "<p>imu\\xff.csv</p>\n"


# --- temporary files: only ours, only dead processes' -----------------------------------------

def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_leftovers_are_only_our_files_of_dead_processes(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    dead = atomic.temporary_name(out / "calib.yaml", _dead_pid())
    alive = atomic.temporary_name(out / "calib.yaml", 1)
    mine = atomic.temporary_name(out / "calib.yaml")
    other_host = out / (dead.name.replace(f"-{atomic._HOST}-", "-000000-")
                        if atomic._HOST != "000000" else dead.name.replace("-000000-", "-ffffff-"))
    users = [out / ".draft.tmp", out / ".calib.yaml.123.abcd.tmp", out / "notes.tmp"]
    for p in (dead, alive, mine, other_host, *users):
        p.write_text("x")
    elsewhere = tmp_path / "session"
    elsewhere.mkdir()
    target = atomic.temporary_name(elsewhere / "data.csv", _dead_pid())
    target.write_text("the user's")
    linked = atomic.temporary_name(out / "x.yaml", _dead_pid())
    linked.symlink_to(target)
    (out / "linked_session").symlink_to(elsewhere)
    removed = set(atomic.remove_leftovers(out))
    assert removed == {dead, mine}
    assert all(p.exists() for p in (alive, other_host, *users, target))
    assert linked.is_symlink()
    assert atomic.remove_leftovers(out / "linked_session", within=out) == []
    assert target.exists()
    assert atomic.remove_leftovers(elsewhere, within=out) == []


def test_a_batch_sweeps_none_of_the_users_files(tmp_path: Path) -> None:
    """``batch --out .`` deleted a user's unrelated ``.draft.tmp`` (every ``.*.tmp``), also in
    the target of a session folder that is a symbolic link, and a failed session deleted
    whatever file was at OUT/<id>/calib.yaml."""
    bad = tmp_path / "bad" / "mav0"
    for sensor in ("imu0", "vicon0"):
        (bad / sensor).mkdir(parents=True)
        (bad / sensor / "data.csv").write_text("not, a, recording\n")
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"sessions:\n  - {{id: a, imu_id: b, date: 2024-01-01, mav0: {bad}}}\n")
    out = tmp_path / "out"
    out.mkdir()
    users = tmp_path / "users_folder"
    users.mkdir()
    (out / "a").symlink_to(users)
    keep = [out / ".draft.tmp", users / ".notes.tmp", users / "calib.yaml",
            atomic.temporary_name(users / "calib.yaml", _dead_pid())]
    for p in keep:
        p.write_text("the user's\n")
    ours = atomic.temporary_name(out / "batch.yaml", _dead_pid())
    ours.write_text("")
    code, _, err = _run("batch", manifest, "--out", out, "--workers", "1", "--quiet")
    assert code == 1 and "1 of 1 sessions failed" in err, err
    assert all(p.read_text() == "the user's\n" for p in keep)
    assert not ours.exists()


def test_a_file_name_that_is_not_utf8_is_printed(result: dict, tmp_path: Path) -> None:
    """Printed to a strict stdout (the default outside the C locale), a name with a byte that
    is not UTF-8 ended the run with exit 70 after its file was written."""
    calib = _with(result, tmp_path, name=os.fsdecode(b"calib\xff.yaml"))
    out = tmp_path / os.fsdecode(b"kalibr\xfe.yaml")
    env = dict(os.environ, PYTHONIOENCODING="utf-8:strict",
               PYTHONPATH=os.pathsep.join([str(Path(__file__).resolve().parents[1]),
                                           os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, "-m", "mocap_calib", "export", calib, "--to", "kalibr",
                           "--out", out], capture_output=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert os.fsencode(out) in proc.stdout and out.is_file()
    assert b"calib\\xff.yaml" in out.read_bytes()  # the file itself is UTF-8


@pytest.mark.slow
def test_an_html_report_of_inputs_named_in_another_encoding(session: Path,
                                                            tmp_path: Path) -> None:
    """``calibrate --html`` of a folder named with a byte that is not UTF-8 ended in
    UnicodeEncodeError (exit 70) when the page was written."""
    import shutil

    folder = tmp_path / os.fsdecode(b"session\xff")
    shutil.copytree(session, folder)
    page = tmp_path / "report.html"
    code, out, err = _run("calibrate", folder, "--out", tmp_path / "calib.yaml", "--html", page,
                          "--segments", "0", "-q")
    assert code == 0, err
    assert "session\\xff" in page.read_text(encoding="utf-8")
    assert load_result(tmp_path / "calib.yaml").session["inputs"]


def test_a_mav0_sensor_yaml_is_held_to_the_flags_ranges(session: Path, tmp_path: Path) -> None:
    import shutil

    folder = tmp_path / "s"
    shutil.copytree(session, folder)
    sensor = folder / "mav0" / "imu0" / "sensor.yaml"
    sensor.write_text("gyroscope_noise_density: 1.0e+30\naccelerometer_noise_density: 2.0e-3\n")
    code, _, err = _run("calibrate", folder, "--out", tmp_path / "c.yaml")
    _refused(code, err, str(sensor), "'gyroscope_noise_density' is 1e+30", "--gyro-noise")
