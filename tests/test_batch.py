"""Batch calibration of a simulated fleet (two airframes, four dates each, a slow bias trend):
results against the simulator's truth, the trend recovered, the Dask engine identical, a
killed batch resumed without redoing work, Ctrl-C leaving no half-written file, one corrupt
session reported while the others succeed, priors from the history, outliers flagged."""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocap_calib.batch.fleet import fleet_summary
from mocap_calib.batch.manifest import load_manifest
from mocap_calib.batch.runner import run_batch
from mocap_calib.cli.main import main
from mocap_calib.core.model.parameters import GYRO_BIAS
from mocap_calib.io.atomic import TMP_TAG, temporary_name
from mocap_calib.io.yaml_io import load_result
from mocap_calib.report.compare import compare
from mocap_calib.workflows.fleet_sim import FleetSimConfig, simulate_fleet

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

ROOT = Path(__file__).resolve().parents[1]
#: Lines of a result file that hold wall-clock times (they differ between any two runs).
TIMING = re.compile(r"^\s*-?\s*(seconds|total_seconds|position_batch_seconds):")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> tuple[Path, dict]:
    return simulate_fleet(tmp_path_factory.mktemp("fleet"), FleetSimConfig(duration=25.0))


@pytest.fixture(scope="module")
def local_run(fleet, tmp_path_factory):
    out = tmp_path_factory.mktemp("local")
    report = run_batch(fleet[0], out, engine="local", workers=2)
    return out, report


def _without_timing(path: Path) -> str:
    """The file without its wall-clock lines and its ``step_seconds:`` block (every line
    indented under it)."""
    out, block = [], None
    for line in path.read_text().splitlines(True):
        indent = len(line) - len(line.lstrip())
        if block is not None and indent > block:
            continue
        block = indent if line.strip() == "step_seconds:" else None
        if block is None and not TIMING.match(line):
            out.append(line)
    return "".join(out)


def _cli(*args: str, **kw) -> subprocess.Popen:
    # As typed in a terminal: Ctrl-C raises KeyboardInterrupt even when the test runner was
    # started in the background (which makes children inherit an ignored SIGINT).
    code = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
            "from mocap_calib.cli.main import main; sys.exit(main(sys.argv[1:]))")
    return subprocess.Popen([sys.executable, "-c", code, "batch", *args],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kw)


def test_every_session_matches_its_truth(fleet, local_run) -> None:
    out, report = local_run
    assert [s.status for s in report.sessions] == ["ok"] * 8
    for s in report.sessions:
        res = load_result(out / s.id / "calib.yaml")
        assert res.session["batch"]["imu_id"] == s.imu_id
        truth = load_result(fleet[0].parent / s.id / "truth.yaml")
        for row in compare(res, truth):
            assert row.z is not None and row.z < 5.0, (s.id, row)


def test_history_recovers_the_simulated_trend(fleet, local_run) -> None:
    out, _ = local_run
    summary = yaml.safe_load((out / "fleet" / "fleet.yaml").read_text())
    assert summary["kind"] == "fleet"
    for imu_id, truth in fleet[1]["airframes"].items():
        rec = summary["imus"][imu_id]
        assert [s["date"] for s in rec["sessions"]] == [
            "2024-03-04", "2024-03-11", "2024-03-18", "2024-03-25"]
        assert rec["outliers"] == []
        for block in ("gyro_bias", "accel_bias"):
            tr = rec["trends"][block]
            rate = np.asarray(truth[f"{block}_rate"])
            slope, sig = np.asarray(tr["slope_per_day"]), np.asarray(tr["sigma_slope_per_day"])
            assert np.all(sig < 0.1 * np.linalg.norm(rate)), (imu_id, block, sig)
            assert np.all(np.abs(slope - rate) < 4 * sig), (imu_id, block, slope, rate, sig)
            at_last = np.asarray(truth[f"{block}_first_date"]) + 21 * rate
            value, vsig = np.asarray(tr["value"]), np.asarray(tr["sigma"])
            assert np.all(np.abs(value - at_last) < 4 * vsig), (imu_id, block, value, at_last)
    rows = (out / "fleet" / "history.csv").read_text().splitlines()
    assert len(rows) == 9 and rows[0].startswith("imu_id,id,date,gyro_bias_0")


def test_an_off_trend_session_is_flagged(fleet, local_run) -> None:
    out, _ = local_run
    entries = load_manifest(fleet[0]).sessions
    done = [(e, load_result(out / e.id / "calib.yaml")) for e in entries]
    bad = done[5][1]
    off = bad.gyro_bias + np.array([0.0, 2e-3, 0.0])  # ~40 sigma off its history
    done[5] = (done[5][0], bad.with_estimates({GYRO_BIAS: replace(bad.estimate(GYRO_BIAS),
                                                                  value=off)}))
    rows, summary = fleet_summary(done)
    flagged = [(o["id"], o["block"]) for rec in summary["imus"].values() for o in rec["outliers"]]
    assert flagged == [(entries[5].id, "gyro_bias")]
    assert [r["outlier"] for r in rows] == [""] * 5 + ["gyro_bias"] + [""] * 2


def test_dask_gives_identical_result_files(fleet, local_run, tmp_path) -> None:
    out, _ = local_run
    report = run_batch(fleet[0], tmp_path, engine="dask", workers=2)
    assert [s.status for s in report.sessions] == ["ok"] * 8
    for s in report.sessions:
        a, b = out / s.id / "calib.yaml", tmp_path / s.id / "calib.yaml"
        text = _without_timing(a)
        assert text == _without_timing(b), s.id
        assert len(text.splitlines()) > 60  # the comparison covered the whole result
    for name in ("fleet.yaml", "history.csv", "trends.csv"):
        assert (out / "fleet" / name).read_bytes() == (tmp_path / "fleet" / name).read_bytes()


def _wait_for_results(out: Path, n: int, proc: subprocess.Popen, timeout: float = 120) -> None:
    t0 = time.monotonic()
    while len(list(out.glob("*/calib.yaml"))) < n:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < timeout, "the batch made no progress"
        time.sleep(0.05)


def test_killed_batch_resumes_without_redoing(fleet, tmp_path) -> None:
    out = tmp_path / "out"
    proc = _cli(str(fleet[0]), "--out", str(out), "--workers", "1", "--quiet")
    _wait_for_results(out, 4, proc)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    kept = {p.parent.name: p.stat().st_mtime_ns for p in out.glob("*/calib.yaml")}
    assert 4 <= len(kept) < 8
    for p in out.glob("*/calib.yaml"):
        load_result(p)  # every result present is whole
    # A kill while the status file was being written leaves its temporary file (the kill
    # above does so now and then): the resumed run clears it, and only it (a user's own
    # '.draft.tmp' stays).
    temporary_name(out / "batch.yaml", proc.pid).write_text("")
    (out / ".draft.tmp").write_text("mine\n")
    report = run_batch(fleet[0], out, workers=2)
    status = {s.id: s.status for s in report.sessions}
    assert {k for k, v in status.items() if v == "skipped"} == set(kept)
    assert sum(v == "ok" for v in status.values()) == 8 - len(kept)
    for sid, mtime in kept.items():
        assert (out / sid / "calib.yaml").stat().st_mtime_ns == mtime
    assert not list(out.rglob(f"*{TMP_TAG}*"))
    assert (out / ".draft.tmp").read_text() == "mine\n"
    # A changed option changes the content hash: that session alone is calibrated again.
    text = fleet[0].read_text().replace("mav0: drone2-2024-03-25",
                                        "mav0: drone2-2024-03-25\n  window: 4.0")
    changed = fleet[0].parent / "changed.yaml"
    changed.write_text(text)
    report = run_batch(changed, out, workers=1)
    assert [s.id for s in report.sessions if s.status == "ok"] == ["drone2-2024-03-25"]


def test_ctrl_c_leaves_no_half_written_file(fleet, tmp_path) -> None:
    out = tmp_path / "out"
    proc = _cli(str(fleet[0]), "--out", str(out), "--workers", "2", "--quiet")
    _wait_for_results(out, 1, proc)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err, err
    assert err.strip().splitlines()[-1] == (f"error: interrupted (SIGINT); the finished sessions "
                                            f"are in {out}; the same command finishes the rest")
    assert not list(out.rglob("*.tmp"))
    for p in out.glob("*/calib.yaml"):
        load_result(p)
    status = yaml.safe_load((out / "batch.yaml").read_text())
    assert {s["id"] for s in status["sessions"] if s["status"] == "ok"} == {
        p.parent.name for p in out.glob("*/calib.yaml")}


def test_one_corrupt_session_fails_alone(fleet, tmp_path, capsys) -> None:
    root = fleet[0].parent
    bad = tmp_path / "bad"
    shutil.copytree(root / "drone1-2024-03-18", bad)
    imu = bad / "mav0" / "imu0" / "data.csv"
    lines = imu.read_text().splitlines(True)
    lines[200] = "1600000001000000000,0.1,zero,0.3,0.1,0.2,9.8\n"
    imu.write_text("".join(lines))
    manifest = tmp_path / "m.yaml"
    manifest.write_text(fleet[0].read_text().replace("mav0: drone1-2024-03-18", f"mav0: {bad}")
                        .replace("mav0: drone", f"mav0: {root}/drone"))
    out = tmp_path / "out"
    code = main(["batch", str(manifest), "--out", str(out), "--workers", "2", "--quiet"])
    captured = capsys.readouterr()
    assert code == 1
    assert "7 calibrated, 0 unchanged since the last run, 1 failed" in captured.out
    status = {s["id"]: s for s in yaml.safe_load((out / "batch.yaml").read_text())["sessions"]}
    failed = status["drone1-2024-03-18"]
    assert failed["status"] == "failed" and "\n" not in failed["error"]
    assert "data.csv" in failed["error"] and "line 201" in failed["error"], failed["error"]
    assert f"drone1-2024-03-18: {failed['error']}" in captured.out
    assert "1 of 8 sessions failed" in captured.err
    assert sum(s["status"] == "ok" for s in status.values()) == 7
    assert not (out / "drone1-2024-03-18" / "calib.yaml").exists()
    assert len(list(out.glob("*/calib.yaml"))) == 7


def test_prior_from_history(fleet, local_run, tmp_path) -> None:
    out, _ = local_run
    report = run_batch(fleet[0], tmp_path, workers=2, prior_from_history=True)
    assert [s.status for s in report.sessions] == ["ok"] * 8
    for k, s in enumerate(report.sessions):
        dates = k % 4
        assert len(s.priors_from) == dates
        res = load_result(tmp_path / s.id / "calib.yaml")
        assert res.session["batch"]["priors_from"] == s.priors_from
        alone = load_result(out / s.id / "calib.yaml")
        truth = load_result(fleet[0].parent / s.id / "truth.yaml")
        for row in compare(res, truth):
            assert row.z is not None and row.z < 5.0, (s.id, row)
        if dates:  # the rig's geometry from the earlier dates entered this calibration
            assert not np.array_equal(res.translation, alone.translation), s.id
        else:
            assert np.array_equal(res.translation, alone.translation)


def _motive_take(path: Path, bodies: dict) -> Path:
    """A Motive CSV (quaternions, meters) with one rigid body per drone; the capture start time
    is the simulator's mocap epoch (1.6e9 s)."""
    names = list(bodies)
    n = min(len(m) for m in bodies.values())
    meta = ["Format Version", "1.23", "Take Name", "swarm", "Capture Frame Rate", "100.000000",
            "Export Frame Rate", "100.000000", "Capture Start Time",
            "2020-09-13 12.26.40.000 PM", "Rotation Type", "Quaternion", "Length Units",
            "Meters", "Coordinate Space", "Global"]
    lines = [",".join(meta), "",
             ",".join(["", "Type", *["Rigid Body"] * 7 * len(names)]),
             ",".join(["", "Name", *[b for b in names for _ in range(7)]]),
             ",".join(["", "ID", *[str(i + 1) for i in range(len(names)) for _ in range(7)]]),
             ",".join(["", "", *(["Rotation"] * 4 + ["Position"] * 3) * len(names)]),
             ",".join(["Frame", "Time (Seconds)", *list("XYZWXYZ") * len(names)])]
    cols = [np.concatenate([m.quat_wxyz[:n, [1, 2, 3, 0]], m.position[:n]], axis=1)
            for m in bodies.values()]
    for k in range(n):
        cells = [repr(float(v)) for c in cols for v in c[k]]
        lines.append(",".join([str(k), f"{k / 100:.6f}", *cells]))
    path.write_text("\n".join(lines) + "\n")
    return path


def test_swarm_one_mocap_take_several_imus(tmp_path) -> None:
    """Three drones flown together: one Motive take holds their three rigid bodies, each IMU
    log picks its own with rigid_body; every calibration matches its drone's truth."""
    from mocap_calib.core.result.calibration import CalibrationResult
    from mocap_calib.io.formats.euroc import write_euroc_imu
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    sims = {f"cf{k + 1}": simulate_flight(SimConfig(seed=70 + k, duration=25.0,
                                                    effects={"time_offset": [0.004]}))
            for k in range(3)}
    _motive_take(tmp_path / "take.csv", {name: s.mocap for name, s in sims.items()})
    for name, s in sims.items():
        write_euroc_imu(tmp_path / f"{name}.csv", s.imu)
    (tmp_path / "swarm.yaml").write_text(
        "defaults: {mocap: take.csv, date: 2024-05-01}\nsessions:\n" + "".join(
            f"  - {{id: {n}-0501, imu_id: {n}, imu: {n}.csv, rigid_body: {n}}}\n" for n in sims))
    report = run_batch(tmp_path / "swarm.yaml", tmp_path / "out", workers=2)
    assert [s.status for s in report.sessions] == ["ok"] * 3, [s.error for s in report.sessions]
    for name, s in sims.items():
        res = load_result(tmp_path / "out" / f"{name}-0501" / "calib.yaml")
        assert any(f"[{name}]" in note for note in res.session["inputs"])
        rows = {r.name: r for r in compare(res, CalibrationResult.from_dict(s.truth))}
        assert set(rows) >= {"R_MI", "p_MI", "gyro_bias", "accel_bias", "time_offset"}
        for row in rows.values():
            assert row.z is not None and row.z < 5.0, (name, row)
    # A wrong body name is that session's one-line error, not the batch's.
    text = (tmp_path / "swarm.yaml").read_text().replace("rigid_body: cf3", "rigid_body: cf9")
    (tmp_path / "swarm.yaml").write_text(text)
    report = run_batch(tmp_path / "swarm.yaml", tmp_path / "out", workers=1)
    assert [s.status for s in report.sessions] == ["skipped", "skipped", "failed"]
    assert "cf9" in report.sessions[2].error and "\n" not in report.sessions[2].error


def test_html_page_lists_every_session_and_the_fleet(fleet, local_run, tmp_path) -> None:
    """``--html`` on a finished batch (every session skipped by its content hash) writes one
    self-contained page naming each session and the fleet's trend."""
    out = tmp_path / "out"
    shutil.copytree(local_run[0], out)
    code = main(["batch", str(fleet[0]), "--out", str(out), "--html", str(out / "batch.html"),
                 "--workers", "1"])
    assert code == 0
    page = (out / "batch.html").read_text()
    for s in local_run[1].sessions:
        assert s.id in page
    assert "<script" not in page and "http://" not in page and "https://" not in page
    assert "drone1" in page and "drone2" in page
