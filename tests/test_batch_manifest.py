"""Batch manifest: every problem one line, all of them before any work; options reach the
calibrate workflow (including rigid_body); the engine API; the progress bar."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from loaded import loaded_by

from mocap_calib.batch.engine import map_jobs
from mocap_calib.batch.manifest import ManifestError, load_manifest
from mocap_calib.batch.progress import render
from mocap_calib.batch.runner import BatchProgress
from mocap_calib.batch.session import SessionJob, run_session
from mocap_calib.cli.main import main
from mocap_calib.errors import InputError


def _files(tmp: Path) -> None:
    (tmp / "imu.csv").write_text("t\n")
    (tmp / "take.csv").write_text("t\n")
    (tmp / "mav0").mkdir()


def test_valid_manifest_defaults_paths_dates(tmp_path: Path) -> None:
    _files(tmp_path)
    (tmp_path / "m.yaml").write_text(
        "defaults:\n  mocap: take.csv\n  columns: broad\n  date: 2024-05-01\n"
        "sessions:\n"
        "  - {id: a, imu_id: d1, imu: imu.csv, rigid_body: drone1, window: 4, robust: false}\n"
        "  - {id: b, imu_id: d2, imu: imu.csv, date: '2024-05-02T10:30:00', columns: null}\n"
        "  - {id: c, imu_id: 7, mav0: mav0, mocap: null, date: 2024-05-03, prior: [imu.csv]}\n")
    m = load_manifest(tmp_path / "m.yaml")
    a, b, c = m.sessions
    ia, ib, ic = a.request.inputs, b.request.inputs, c.request.inputs
    assert ia.imu == (tmp_path / "imu.csv",) and ia.mocap == (tmp_path / "take.csv",)
    assert ia.poses.rigid_body == "drone1" and a.request.options.window == 4.0
    assert a.request.options.robust is False
    assert ia.columns == "broad" and a.date == "2024-05-01"
    assert ib.columns is None  # null unsets the default
    assert b.time_ns - a.time_ns == (24 + 10.5) * 3600 * 10**9
    assert c.imu_id == "7" and ic.mav0 == (tmp_path / "mav0",)
    assert ic.mocap == () and c.request.prior == (tmp_path / "imu.csv",)


def test_every_problem_one_line_before_any_work(tmp_path: Path, capsys) -> None:
    _files(tmp_path)
    (tmp_path / "m.yaml").write_text(
        "sessions:\n"
        "  - {id: a, imu_id: d1, date: 2024-05-01, imu: imu.csv, mocap: missing.csv}\n"
        "  - {id: b, imu_id: d1, date: 2024-05-02, imu: imu.csv, mocap: take.csv, windw: 3}\n"
        "  - {id: a, imu_id: d2, date: 2024-05-03, imu: imu.csv, mocap: take.csv}\n"
        "  - {id: d, imu_id: d2, date: 2024-05-04, imu: imu.csv, mocap: take.csv, out: x}\n"
        "  - {id: e, imu_id: d2, date: someday, mav0: mav0, window: wide}\n")
    out = tmp_path / "out"
    code = main(["batch", str(tmp_path / "m.yaml"), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert not out.exists(), "work started despite manifest errors"
    assert all(line.startswith(f"error: {tmp_path / 'm.yaml'}: session ") for line in err), err
    expected = [("'a' (#1)", "mocap file", "missing.csv not found"),
                ("'b' (#2)", "unknown key 'windw'", "did you mean 'window'?"),
                ("'a' (#3)", "duplicate id (also session #1)", "own id"),
                ("'d' (#4)", "key 'out' is not a batch option", "OUT/<id>/calib.yaml"),
                ("'e' (#5)", "unreadable date 'someday'", "2024-03-01"),
                ("'e' (#5)", "window must be a number", "give a number")]
    assert len(err) == len(expected), err
    for line, words in zip(err, expected, strict=True):
        assert all(w in line for w in words), (line, words)


def test_structure_errors(tmp_path: Path) -> None:
    _files(tmp_path)
    for text, words in (("sessions: []\n", "no sessions"),
                        ("sessions:\n  - {id: a, imu_id: x, date: 2024-01-01, mav0: mav0}\n"
                         "session: x\n", "unknown key 'session'"),
                        ("sessions:\n  - just a string\n", "is not a mapping"),
                        ("sessions:\n  - {id: 'a/b', imu_id: x, date: 2024-01-01, mav0: mav0}\n",
                         "invalid id"),
                        ("sessions:\n  - {id: a, imu_id: x, date: 2024-01-01, imu: imu.csv}\n",
                         "no inputs"),
                        ("sessions:\n  - {id: a, imu_id: x, date: 2024-01-01, mav0: mav0,"
                         " model: base+warp}\n", "unknown effect 'warp'"),
                        ("sessions: [\n", "not valid YAML")):
        (tmp_path / "m.yaml").write_text(text)
        with pytest.raises(InputError) as exc:
            load_manifest(tmp_path / "m.yaml")
        assert words in str(exc.value), (text, str(exc.value))
        if isinstance(exc.value, ManifestError):
            assert len(exc.value.problems) == 1, exc.value.problems


def test_options_reach_the_calibrate_workflow(tmp_path: Path, monkeypatch) -> None:
    """rigid_body and the reading options go into the workflow's InputSpec, the solver options
    into CalibrationOptions: checked where the workflow reads the session."""
    import mocap_calib.workflows.calibrate as wf

    _files(tmp_path)
    (tmp_path / "m.yaml").write_text(
        "sessions:\n  - {id: a, imu_id: d1, date: 2024-05-01, imu: imu.csv, mocap: take.csv,"
        " rigid_body: drone2, columns: broad, time_unit: ms}\n")
    seen = {}

    def fake_load(spec, *_):
        seen["spec"] = spec
        raise InputError("stop here")

    monkeypatch.setattr(wf, "load_session", fake_load)
    request = load_manifest(tmp_path / "m.yaml").sessions[0].request
    with pytest.raises(InputError, match="stop here"):
        run_session(SessionJob("a", request))
    spec = seen["spec"]
    assert spec.poses.rigid_body == "drone2" and spec.columns == "broad"
    assert spec.time_unit == "ms"
    assert spec.imu == (tmp_path / "imu.csv",) and spec.mocap == (tmp_path / "take.csv",)


def _square(x: int) -> int:
    if x == 3:
        raise InputError("three is\nnot allowed")
    if x == 4:
        raise ZeroDivisionError("boom")
    if x == 5:
        os._exit(9)  # the worker process dies
    return x * x


@pytest.mark.slow
def test_engine_runs_any_function_and_survives_failures() -> None:
    outs = map_jobs(_square, list(range(7)), "local", workers=2)
    assert [o.index for o in outs] == list(range(7))
    assert [o.value for o in outs if o.ok] == [0, 1, 4, 36]
    assert outs[3].error == "three is not allowed"
    assert outs[4].error == "internal error: ZeroDivisionError: boom"
    assert not outs[5].ok and "worker process died" in outs[5].error


def test_engine_choice_errors(monkeypatch) -> None:
    for args, words in ((("cloud",), "unknown --engine 'cloud'"),
                        (("local", 0), "--workers 0"),
                        (("local", 1, "tcp://x:1"), "--scheduler needs --engine dask"),
                        (("dask", 2, "tcp://x:1"), "drop --workers")):
        with pytest.raises(InputError, match=words):
            map_jobs(_square, [1], *args)
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "distributed" else real(name, *a))
    with pytest.raises(InputError, match=r"pip install 'mocap-calib\[cluster\]'"):
        map_jobs(_square, [1], "dask")


def test_progress_line() -> None:
    line = render(BatchProgress(total=8, done=4, running=2, failed=1, skipped=1, eta_s=75.0,
                                last="b ok"))
    assert line == ("[############............] 4/8 done, 2 running, 1 skipped, 1 failed, "
                    "ETA 1:15  (b ok)")
    assert "ETA --:--" in render(BatchProgress(total=3))


def test_dask_is_imported_only_by_the_dask_engine() -> None:

    code = ("from mocap_calib.cli.main import _register_commands\n"
            "_register_commands()\n"
            "import mocap_calib.batch.runner, mocap_calib.batch.fleet, mocap_calib.batch.progress\n"
            "from mocap_calib.batch.engine import make_engine\n"
            "make_engine('local', 1)\n")
    assert loaded_by(code, ["dask", "distributed"]) == []


def test_manifest_keys_are_the_calibrate_options() -> None:
    """Every option of 'mocap-calib calibrate' is a manifest key, and nothing else (out, rrd,
    report, html and quiet belong to the batch)."""
    from mocap_calib.batch.manifest import ARG_KEYS, REFUSED
    from mocap_calib.cli.build import option_names  # noqa: F401
    from mocap_calib.cli.main import app, main

    main(["calibrate", "--help"])  # registers the commands
    import typer

    cmd = typer.main.get_command(app).commands["calibrate"]
    cli = {p.name for p in cmd.params if p.name != "help"}
    assert set(ARG_KEYS) == cli - set(REFUSED)
