"""The series the recording and the HTML report draw are computed by the core once, only when one
of them is written: a plain ``calibrate`` computes none, ``--rrd`` and ``--html`` together share
one computation (one IMU prediction and one dead reckoning for a short session), and a recording
alone computes none of the report's figures.

One 30 s simulated session is calibrated once; the command then runs with that solution (its
``run_calibration`` replaced), so that each case costs only its outputs.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from mocap_calib.cli.main import main
from mocap_calib.core.diagnosis import outputs
from mocap_calib.workflows import calibrate
from mocap_calib.workflows.simulate import simulate_to_folder

pytestmark = pytest.mark.slow  # a full calibration


@pytest.fixture(scope="module")
def solved(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    folder = tmp_path_factory.mktemp("series") / "session"
    simulate_to_folder(folder, seed=5, duration=30.0, effects=["time_offset=0.004"])
    request = calibrate.CalibrateRequest(inputs=calibrate.InputSpec(mav0=folder))
    return folder, calibrate.run_calibration(request)


def _calibrate(solved: tuple[Path, Any], monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
               *options: str) -> Counter[str]:
    """Run ``calibrate`` on the stored solution with ``options`` (paths under ``tmp_path``);
    returns how often the core's series functions were called."""
    folder, solution = solved
    calls: Counter[str] = Counter()
    monkeypatch.setattr(calibrate, "run_calibration", lambda request, progress=None: solution)
    for name in ("output_series", "predict_imu", "dead_reckoning", "analyse_residuals"):
        real = getattr(outputs, name)

        def counted(*args: Any, _real: Any = real, _name: str = name, **kwargs: Any) -> Any:
            calls[_name] += 1
            return _real(*args, **kwargs)

        monkeypatch.setattr(outputs, name, counted)
    args = [a if not a.startswith("@") else str(tmp_path / a[1:]) for a in options]
    assert main(["calibrate", str(folder), "--out", str(tmp_path / "r.yaml"), *args, "-q"]) == 0
    return calls


def test_a_plain_calibrate_computes_no_series(solved, monkeypatch, tmp_path: Path) -> None:
    calls = _calibrate(solved, monkeypatch, tmp_path)
    assert (tmp_path / "r.yaml").is_file()
    assert calls == Counter()


def test_rrd_and_html_share_one_computation(solved, monkeypatch, tmp_path: Path) -> None:
    calls = _calibrate(solved, monkeypatch, tmp_path, "--rrd", "@c.rrd", "--html", "@c.html")
    assert (tmp_path / "c.rrd").stat().st_size > 0 and (tmp_path / "c.html").stat().st_size > 0
    # 30 s: the report's spectra span the whole session and its dead reckoning is every 10 s,
    # as the recording's: each is computed once.
    assert calls == Counter(output_series=1, predict_imu=1, dead_reckoning=1,
                            analyse_residuals=1)


def test_a_recording_alone_computes_no_report_figures(solved, monkeypatch,
                                                      tmp_path: Path) -> None:
    calls = _calibrate(solved, monkeypatch, tmp_path, "--rrd", "@c.rrd")
    assert calls == Counter(output_series=1, predict_imu=1, dead_reckoning=1)
    series = outputs.output_series(solved[1][0], recording=True)
    assert series.first is not None and series.first.figures is None
    assert series.first.imu is not None and series.first.dead_reckoning is not None


def test_a_report_alone_computes_no_recording_series(solved, monkeypatch,
                                                     tmp_path: Path) -> None:
    calls = _calibrate(solved, monkeypatch, tmp_path, "--html", "@c.html")
    # The report's own prediction (its middle span: the whole 30 s) and dead reckoning.
    assert calls == Counter(output_series=1, predict_imu=1, dead_reckoning=1,
                            analyse_residuals=1)
    series = outputs.output_series(solved[1][0], report=True)
    assert series.first is not None and series.first.figures is not None
    assert series.first.imu is None and series.first.dead_reckoning is None
    assert series.solver is None and series.steps == ()
