"""A step that fails and is stepped over is never silent: each one forced here (a segment's
refit, a sensitivity refit, the position stage's settling rounds, an effect test's statistic,
a diagnosis candidate's fit) leaves a ``degraded`` entry in the result, a line in the text
summary and an entry under ``degraded:`` in the result file; a clean run has none."""

from __future__ import annotations

import numpy as np
import pytest

from mocap_calib.core.model.effects import Model
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.errors import ConvergenceError
from mocap_calib.report.text import summary_table
from mocap_calib.sim.flight import SimConfig, simulate_flight

pytestmark = pytest.mark.slow  # full calibrations: not in the quick subset

QUIET = CalibrationOptions(segments=0, sensitivity=False, effect_tests=False)


@pytest.fixture(scope="module")
def sim():
    return simulate_flight(SimConfig(seed=61, duration=30.0, effects={"time_offset": [0.003]}))


def _entries(r: CalibrationResult, what: str) -> list:
    return [x for x in r.degraded if x.what.startswith(what)]


def _shown(r: CalibrationResult, what: str) -> None:
    """The entry is in the summary (one line each) and in the file, and survives reading."""
    lines = [x for x in summary_table(r).splitlines() if x.startswith(f"DEGRADED {what}")]
    assert lines, summary_table(r)
    d = r.to_dict()
    assert any(x["what"].startswith(what) for x in d["degraded"]), d.get("degraded")
    assert CalibrationResult.from_dict(d).degraded == r.degraded


def test_a_clean_run_has_no_degraded_entry(sim) -> None:
    r = calibrate(sim.imu, sim.mocap, CalibrationOptions(segments=3, sensitivity=False))
    assert r.degraded == (), r.degraded
    assert "degraded" not in r.to_dict()
    assert "DEGRADED" not in summary_table(r)


def test_a_failed_segment_refit_is_degraded(sim, monkeypatch) -> None:
    from mocap_calib.core.uncertainty import segments

    def fail(*_a, **_k):
        raise ConvergenceError("forced: the segment's solve did not converge")

    monkeypatch.setattr(segments, "refit", fail)
    r = calibrate(sim.imu, sim.mocap, CalibrationOptions(segments=3, sensitivity=False,
                                                         effect_tests=False))
    (entry,) = _entries(r, "segment consistency")
    assert "segment 1 could not be calibrated on its own" in entry.why
    assert "forced" in entry.why and "consistency factor" in entry.consequence
    assert r.consistency is not None and "forced" in r.consistency.note
    assert all(e.terms is None or e.terms.consistency_factor == 1.0
               for e in r.estimates.values())
    _shown(r, "segment consistency")


def test_a_failed_sensitivity_refit_is_degraded(sim, monkeypatch) -> None:
    from mocap_calib.core.uncertainty import sensitivity

    real = sensitivity.refit

    def fail_x3(pos, model, which, *, noise=None, **kw):
        if noise is not None and noise.gyroscope_noise_density > pos.noise.gyroscope_noise_density:
            raise np.linalg.LinAlgError("forced: singular system")
        return real(pos, model, which, noise=noise, **kw)

    monkeypatch.setattr(sensitivity, "refit", fail_x3)
    r = calibrate(sim.imu, sim.mocap, CalibrationOptions(segments=0, effect_tests=False))
    (entry,) = _entries(r, "sensitivity")
    assert entry.what == "sensitivity x3" and "forced: singular system" in entry.why
    assert r.sensitivity is not None and "x3" not in r.sensitivity.moved_statistical
    assert "x0.333" in r.sensitivity.moved_statistical  # the other alternatives still ran
    _shown(r, "sensitivity x3")


def test_settling_rounds_cut_at_their_cap_are_degraded(sim, monkeypatch) -> None:
    from mocap_calib.core.pipeline.calibrate import SETTLING_ROUNDS
    from mocap_calib.core.position import settle

    real = settle.settle

    def never_settled(*a, **k):
        real(*a, **k)
        return True, 1.0  # the levels moved every round

    monkeypatch.setattr(settle, "settle", never_settled)
    r = calibrate(sim.imu, sim.mocap, QUIET)
    assert r.solver.rounds == SETTLING_ROUNDS
    (entry,) = _entries(r, "position stage")
    assert f"cap ({SETTLING_ROUNDS})" in entry.why
    _shown(r, "position stage")


def test_an_effect_statistic_that_cannot_be_computed_is_degraded(sim, monkeypatch) -> None:
    from mocap_calib.core.checks import effect_scores

    def fail(*_a, **_k):
        raise np.linalg.LinAlgError("forced: singular information")

    monkeypatch.setattr(effect_scores, "chi2_logsf", fail)
    r = calibrate(sim.imu, sim.mocap, CalibrationOptions(segments=0, sensitivity=False))
    entries = _entries(r, "effect test")
    assert r.effect_tests is not None
    assert {x.what for x in entries} == {f"effect test {c.effect}"
                                         for c in r.effect_tests.candidates}
    assert all("model-based statistic" in x.why and "forced" in x.why for x in entries)
    _shown(r, "effect test")


def test_a_diagnosis_candidate_that_cannot_be_fitted_is_degraded(sim, monkeypatch) -> None:
    from mocap_calib.core.diagnosis import diagnose as dg

    real = dg._Session.fit

    # Only the candidates the score test finds significant are refitted: the session's clock
    # offset is the one (from the base model, which lacks it).
    def fail_offset(self, m, base, nz, extra=None, covariance=True):
        if m.effects and m.effects[-1] == "time_offset" and not covariance:
            raise RuntimeError("forced: indeterminate system")
        return real(self, m, base, nz, extra, covariance)

    monkeypatch.setattr(dg._Session, "fit", fail_offset)
    opts = dg.DiagnoseOptions(start_model=Model(), candidates=("time_offset", "accel_delay"),
                              max_steps=1, calibration=QUIET)
    report = dg.diagnose(sim.imu, sim.mocap, opts)
    (entry,) = [x for x in report.degraded if "time_offset" in x.why]
    assert entry.what == "diagnosis step 1" and "forced" in entry.why
    assert any("time_offset could not be fitted" in n for n in report.notes)
    assert "time_offset" not in report.found
    d = report.to_dict()
    assert d["degraded"] == [entry.to_dict()]
