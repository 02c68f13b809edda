"""The rerun recording shows what the result says, and ``mocap-calib view`` behaves headlessly.

A 30 s simulated session is calibrated once; its recording is read back with
``rerun.chunk.RrdReader`` and compared with the result's own figures.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mocap_calib.cli.main import main
from mocap_calib.core.diagnosis.dead_reckoning import dead_reckoning
from mocap_calib.core.diagnosis.outputs import output_series
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.errors import InputError
from mocap_calib.report.text import summary_table
from mocap_calib.sim.flight import SimConfig, SimulatedSession, simulate_flight
from mocap_calib.viz.recording import write_calibration_recording

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

AXES = ("x", "y", "z")
STAGES = ("attitude", "velocity", "position")


class Recording:
    """Chunks of an ``.rrd`` file grouped by entity path (leading ``/`` stripped)."""

    def __init__(self, path: Path) -> None:
        from rerun.chunk import RrdReader

        self.batches: dict[str, list[Any]] = defaultdict(list)
        for chunk in RrdReader(path).stream():
            self.batches[chunk.entity_path.lstrip("/")].append(chunk.to_record_batch())

    def columns(self, entity: str) -> set[str]:
        return {name for b in self.batches.get(entity, []) for name in b.schema.names}

    def column(self, entity: str, name: str) -> list[Any]:
        """All values of a column across the entity's chunks (rows in chunk order)."""
        out: list[Any] = []
        for b in self.batches[entity]:
            if name in b.schema.names:
                out.extend(b.column(name).to_pylist())
        return out

    def scalars(self, entity: str) -> tuple[np.ndarray, np.ndarray]:
        """(times in s, values) of a scalar series on the ``t`` timeline."""
        t, v = [], []
        for b in self.batches[entity]:
            if "Scalars:scalars" in b.schema.names and "t" in b.schema.names:
                t.append(b.column("t").cast("int64").to_numpy() * 1e-9)
                v.append(np.concatenate(b.column("Scalars:scalars").to_pylist()))
        return np.concatenate(t), np.concatenate(v)

    def times(self) -> np.ndarray:
        """Every stamp on the ``t`` timeline (s)."""
        return np.concatenate([b.column("t").cast("int64").to_numpy() * 1e-9
                               for bs in self.batches.values() for b in bs
                               if "t" in b.schema.names])


@pytest.fixture(scope="module")
def calibrated() -> tuple[SimulatedSession, CalibrationResult]:
    sim = simulate_flight(SimConfig(seed=11, duration=30, effects={"time_offset": [0.004]}))
    return sim, calibrate(sim.imu, sim.mocap)


@pytest.fixture(scope="module")
def rrd(calibrated: tuple[SimulatedSession, CalibrationResult],
        tmp_path_factory: pytest.TempPathFactory) -> Path:
    sim, result = calibrated
    steps = [("base model", result.diagnostics.residuals)]
    path = tmp_path_factory.mktemp("viz") / "sub" / "calib.rrd"
    series = output_series(result, recording=True, steps=steps)
    written = write_calibration_recording(path, result, series)
    assert written == path and path.stat().st_size > 0
    return path


@pytest.fixture(scope="module")
def rec(rrd: Path) -> Recording:
    return Recording(rrd)


def test_entities_exist(rec: Recording) -> None:
    expected = ["summary", "checks", "guide", "world/mocap/trajectory", "world/marker", "world/imu",
                "world/imu/lever", "world/gravity", "solver/cost", "solver/time_offset"]
    expected += [f"world/dead_reckoning/{k}" for k in ("mocap", "before", "after")]
    expected += [f"dead_reckoning/{k}/position_error" for k in ("before", "after")]
    for stage in STAGES:
        expected.append(f"residuals/{stage}/weight")
        expected += [f"residuals/{stage}/{ba}/{a}" for ba in ("before", "after") for a in AXES]
        expected += [f"diagnose/base_model/{stage}/after/{a}" for a in AXES]
    expected += [f"residuals/position/rotation/{ba}/{a}" for ba in ("before", "after")
                 for a in AXES]
    expected += [f"imu/{s}/{k}/{a}" for s in ("gyro", "accel")
                 for k in ("measured", "predicted", "difference") for a in AXES]
    expected += [f"solver/{k}/{a}" for k in ("p_MI", "R_MI", "gyro_bias", "accel_bias")
                 for a in AXES]
    missing = [e for e in expected if e not in rec.batches]
    assert not missing, missing
    # The IMU frame is a time series of transforms; the solver is on the iteration timeline.
    assert {"t", "Transform3D:translation", "Transform3D:quaternion"} <= rec.columns("world/imu")
    assert "TransformAxes3D:axis_length" in rec.columns("world/imu")
    assert "iteration" in rec.columns("solver/cost")
    assert "Arrows3D:vectors" in rec.columns("world/gravity")
    assert "LineStrips3D:strips" in rec.columns("world/mocap/trajectory")


def test_after_residual_rms_equals_result(rec: Recording,
                                          calibrated: tuple[Any, CalibrationResult]) -> None:
    _, result = calibrated
    for st in result.stages:
        series = result.diagnostics.residuals[st.name]
        for i, a in enumerate(AXES):
            t, v = rec.scalars(f"residuals/{st.name}/after/{a}")
            assert len(v) == len(series.t), "residual series must be complete"
            np.testing.assert_allclose(np.sqrt(np.mean(v**2)), st.rms_after[i], rtol=1e-9)
            _, b = rec.scalars(f"residuals/{st.name}/before/{a}")
            np.testing.assert_allclose(np.sqrt(np.mean(b**2)), st.rms_before[i], rtol=1e-9)
            np.testing.assert_allclose(np.sort(t), np.sort(series.t), atol=1e-9)
        if st.rms_rotation_deg is not None:
            for i, a in enumerate(AXES):
                _, v = rec.scalars(f"residuals/{st.name}/rotation/after/{a}")
                np.testing.assert_allclose(np.sqrt(np.mean(v**2)), st.rms_rotation_deg[i],
                                           rtol=1e-9)


def test_time_axis_spans_session(rec: Recording, calibrated: tuple[Any, Any]) -> None:
    _, result = calibrated
    tau = result.diagnostics.trace.session.tau
    t = rec.times()
    assert t.min() == pytest.approx(tau[0], abs=1e-6)
    assert t.max() >= tau[-1] - 0.05  # the last pose may fall between decimated samples
    assert t.max() <= tau[-1] + 1e-6
    tm, _ = rec.scalars("imu/gyro/difference/x")
    assert tm.min() < tau[0] + 5.0 and tm.max() > tau[-1] - 5.0


def test_summary_text(rec: Recording, calibrated: tuple[Any, CalibrationResult]) -> None:
    _, result = calibrated
    texts = [x for row in rec.column("summary", "TextDocument:text") for x in row]
    assert texts == [summary_table(result)]
    checks = [x for row in rec.column("checks", "TextDocument:text") for x in row]
    assert len(checks) == 1 and "consistency (3 segments)" in checks[0]
    assert "gyro_bias" in texts[0] and "position" in texts[0]


def test_solver_iterations(rec: Recording, calibrated: tuple[Any, CalibrationResult]) -> None:
    _, result = calibrated
    its = result.diagnostics.iterations
    assert rec.column("solver/cost", "iteration") == [h["iteration"] for h in its]
    last = np.concatenate(rec.column("solver/cost", "Scalars:scalars"))[-1]
    assert last == pytest.approx(its[-1]["cost"])


def test_imu_difference_is_measured_minus_predicted(
        rec: Recording, calibrated: tuple[SimulatedSession, CalibrationResult]) -> None:
    """The difference is centred on zero within 4 standard errors of its mean on every axis,
    while the simulator's true biases are far larger (gyro x, y: 0.012-0.014 rad/s against a
    tolerance of 0.0016; accel x: 0.12 m/s^2 against 0.046): a prediction that leaves out the
    bias (or any term of that size) fails. Measured: |mean| 6e-5 rad/s and 1.3e-3 m/s^2 at most."""
    sim, _ = calibrated
    for s, bias in (("gyro", sim.gyro_bias_true), ("accel", sim.accel_bias_true)):
        tol = []
        for a in AXES:
            _, m = rec.scalars(f"imu/{s}/measured/{a}")
            _, p = rec.scalars(f"imu/{s}/predicted/{a}")
            _, d = rec.scalars(f"imu/{s}/difference/{a}")
            np.testing.assert_allclose(d, m - p, atol=1e-12)
            tol.append(4.0 * np.std(d) / np.sqrt(len(d)))
            assert abs(np.mean(d)) < tol[-1], (s, a, np.mean(d), tol[-1])
        assert np.max(np.abs(bias.mean(axis=0)) / np.array(tol)) > 2.0, s  # the check can fail
    t, _ = rec.scalars("imu/gyro/measured/x")
    assert 1.0 / np.median(np.diff(t)) <= 50.0 + 1e-6


def test_dead_reckoning_after_follows_mocap(calibrated: tuple[Any, CalibrationResult]) -> None:
    _, result = calibrated
    ex = result.diagnostics.trace
    dr = dead_reckoning(ex.session, ex.model_state)
    assert dr is not None and len(dr.tau) >= 2
    after, before = dr.position_error("after"), dr.position_error("before")
    assert np.median(after) < 0.1  # m after 2 s: mocap and IMU noise only
    assert np.median(after) < 0.3 * np.median(before)
    assert np.median(dr.attitude_error("after")) < np.median(dr.attitude_error("before"))


def test_without_diagnostics(calibrated: tuple[SimulatedSession, CalibrationResult],
                             tmp_path: Path) -> None:
    """A result read back from YAML has no diagnostics: 3D, IMU and summary only."""
    sim, result = calibrated
    bare = dataclasses.replace(result, diagnostics=None)
    series = output_series(bare, recording=True, imu=sim.imu, mocap=sim.mocap)
    rec = Recording(write_calibration_recording(tmp_path / "bare.rrd", bare, series))
    assert "world/imu" in rec.batches and "imu/accel/difference/z" in rec.batches
    assert not any(e.startswith(("residuals", "solver")) for e in rec.batches)
    with pytest.raises(InputError):
        write_calibration_recording(tmp_path, result, series)


def test_view_without_display_prints_instruction(rrd: Path, monkeypatch: pytest.MonkeyPatch,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    from mocap_calib.workflows import view

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if not sys.platform.startswith("linux"):
        monkeypatch.setattr(view, "has_display", lambda: False)
    assert not view.has_display()
    monkeypatch.setattr(subprocess, "call", lambda *a, **k: pytest.fail("viewer spawned"))
    assert main(["view", str(rrd)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1
    assert f"rerun {rrd}" in out[0] and "--web-viewer" in out[0]


@pytest.mark.parametrize("name", ["missing.rrd", "not_rrd.rrd"])
def test_view_bad_file_exits_2(name: str, tmp_path: Path,
                               capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "not_rrd.rrd").write_text("a,b\n1,2\n")
    assert main(["view", str(tmp_path / name)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1
    assert "Traceback" not in err


def test_importing_viz_does_not_import_rerun() -> None:
    code = ("import sys, mocap_calib.viz.recording, mocap_calib.cli.main as m; "
            "m._register_commands(); "
            "assert 'rerun' not in sys.modules, sorted(k for k in sys.modules if 'rerun' in k)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_view_spawns_viewer_with_display(rrd: Path, monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    from mocap_calib.workflows import view

    calls: list[list[str]] = []
    monkeypatch.setattr(view, "has_display", lambda: True)
    monkeypatch.setattr(view, "viewer_executable", lambda: "/opt/rerun")
    monkeypatch.setattr(subprocess, "call", lambda argv: calls.append(argv) or 0)
    assert main(["view", str(rrd)]) == 0
    assert calls == [["/opt/rerun", str(rrd)]]
    monkeypatch.setattr(subprocess, "call", lambda argv: 3)
    assert main(["view", str(rrd)]) == 1
    assert "--web-viewer" in capsys.readouterr().err


def test_a_session_without_imu_gaps_shows_none(rec: Recording,
                                               calibrated: tuple[Any, CalibrationResult]) -> None:
    _, result = calibrated
    assert result.imu_gaps.count == 0
    assert not [e for e in rec.batches if e.startswith("imu_gaps")]
