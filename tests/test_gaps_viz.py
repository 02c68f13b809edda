"""The IMU gaps are shown where they are: spans in the rerun recording and shaded spans in the
HTML report, at the times the simulator punched them (IMU clock moved to the mocap clock by the
simulated clock offset), and none for a session without gaps (tests/test_viz.py,
tests/test_html_report.py)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from test_html_report import Page
from test_viz import Recording

from mocap_calib.core.diagnosis.outputs import output_series
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.core.policy import IMU_BRIDGE_MAX_S, IMU_TRIM_START_S
from mocap_calib.sim.flight import SimConfig, simulate_flight
from mocap_calib.viz.recording import write_calibration_recording
from mocap_calib.workflows.report_files.pages import RunClock, write_calibration_html

T_D = 0.004


@pytest.fixture(scope="module")
def gappy(tmp_path_factory: pytest.TempPathFactory):
    sim = simulate_flight(SimConfig(seed=7, duration=40.0, effects={
        "time_offset": [T_D], "imu_dropouts": [10], "imu_stalls": [0.8]}))
    result = calibrate(sim.imu, sim.mocap, CalibrationOptions(segments=0, sensitivity=False))
    out = tmp_path_factory.mktemp("gapsviz")
    series = output_series(result, recording=True, report=True)
    rrd = write_calibration_recording(out / "c.rrd", result, series)
    html = write_calibration_html(out / "c.html", result, series, [], RunClock())
    return sim, result, rrd, html


def _truth_spans(sim) -> np.ndarray:
    """The simulated gaps (overlapping ones merged; the one at the log's start is trimmed, not
    a gap) on the mocap clock: IMU time + clock origins' difference + the true offset."""
    spans = sorted((a, a + d) for a, d in sim.truth["simulation"]["imu_gaps_start_length_s"]
                   if a - sim.imu.t[0] >= IMU_TRIM_START_S)
    merged: list[list[float]] = []
    for a, b in spans:
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    shift = (sim.imu.time_origin_ns - sim.mocap.time_origin_ns) * 1e-9 + T_D
    return np.array(merged) + shift


def _match(shown: np.ndarray, truth: np.ndarray, dt: float) -> None:
    """Every simulated gap is one shown span and vice versa: its start within one IMU step
    before the punched start (the last sample kept), its end within one step after."""
    assert len(shown) == len(truth), (shown, truth)
    tol = 0.5e-3  # the estimated clock offset's error, far below this
    for (a, b), (ta, tb) in zip(shown, truth, strict=True):
        assert ta - dt - tol <= a <= ta + tol, (a, ta)
        assert tb - tol <= b <= tb + dt + tol, (b, tb)


def test_the_recording_holds_one_span_per_gap_at_its_time(gappy) -> None:
    sim, result, rrd, _ = gappy
    rec = Recording(rrd)
    names = sorted(e for e in rec.batches if e.startswith("imu_gaps/"))
    assert len(names) == result.imu_gaps.count >= 8
    shown = []
    for e in names:
        t, v = rec.scalars(e)
        assert len(t) == 2 and np.all(v == 0.0)
        shown.append(np.sort(t))
    dt = float(np.median(np.diff(sim.imu.t)))
    _match(np.array(sorted(shown, key=lambda x: x[0])), _truth_spans(sim), dt)
    # The legend says which gap split the session (the 0.8 s stall) and which were bridged.
    labels = [str(rec.column(e, "SeriesLines:names")) for e in names]
    assert sum("split" in x for x in labels) == result.imu_gaps.split == 1
    assert sum("bridged" in x for x in labels) == result.imu_gaps.bridged


def test_the_html_shades_the_gaps_at_their_times(gappy) -> None:
    sim, result, _, html = gappy
    text = Path(html).read_text(encoding="utf-8")
    page = Page(text)
    dt = float(np.median(np.diff(sim.imu.t)))
    truth = _truth_spans(sim)
    for fig in ("fig-gaps", "fig-residuals-position", "fig-residuals-attitude"):
        data = page.ids[fig]
        assert int(data["data-imu-gaps"]) == result.imu_gaps.count
        shown = np.stack([[float(x) for x in data["data-imu-gap-starts-s"].split(",")],
                          [float(x) for x in data["data-imu-gap-ends-s"].split(",")]], axis=1)
        _match(shown, truth, dt)
    table = re.search(r'id="imu-gaps-table".*?</table>', text, re.S)
    assert table is not None
    assert table.group(0).count(">split<") == int(np.sum(np.diff(truth, axis=1)
                                                         > IMU_BRIDGE_MAX_S)) == 1
    assert table.group(0).count(">bridged<") == result.imu_gaps.bridged
