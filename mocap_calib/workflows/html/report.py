"""The HTML reports of the commands: the figures computed for them (residual spectra against
the noise floor, dead reckoning), their provenance, and the file.

The computations live here (the workflow layer), the drawing in :mod:`mocap_calib.report.html`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import signal

from mocap_calib.core.diagnosis.dead_reckoning import dead_reckoning
from mocap_calib.core.diagnosis.predict import analyse_residuals, model_forward, predict_imu
from mocap_calib.core.model.effects import EFFECTS
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.stages.figures import ResidualSeries, StageStats
from mocap_calib.io.yaml_io import save_text
from mocap_calib.report.html import Provenance, Section, render_html
from mocap_calib.report.html.calibration import CalibrationExtras, StageSpectrum
from mocap_calib.workflows.html.provenance import RunClock, provenance

__all__ = ["calibration_extras", "write_report", "RunClock"]


def _welch(t: np.ndarray, x: np.ndarray, max_nperseg: int = 1024
           ) -> tuple[np.ndarray, np.ndarray] | None:
    """Welch PSD of samples ``x(t)`` taken as evenly spaced at their median step."""
    if len(t) < 16:
        return None
    order = np.argsort(t, kind="stable")
    fs = 1.0 / float(np.median(np.diff(t[order]))) if len(t) > 1 else 1.0
    nper = int(min(max_nperseg, max(8, len(t) // 4)))
    f, p = signal.welch(x[order], fs=fs, nperseg=nper, axis=0)
    return f, p


def stage_spectrum(series: ResidualSeries, stats: StageStats) -> StageSpectrum | None:
    """Residual spectra of a stage with the white floor of its noise model: per axis the
    variance at which chi2/dof would be 1 (``rms_after^2 / chi2_per_dof``), as ``2 var / fs``."""
    b = _welch(series.t, series.before)
    a = _welch(series.t, series.after)
    if a is None or b is None:
        return None
    fs = 2.0 * float(a[0][-1])
    var = np.asarray(stats.rms_after) ** 2 / max(stats.chi2_per_dof, 1e-12)
    return StageSpectrum(series.unit, a[0], b[1], a[1], 2.0 * var / fs)


#: The IMU-domain spectra use at most this much of the session (its middle), so that the report
#: stays cheap for long sessions; a few minutes give Welch estimates with dozens of averages.
SPECTRUM_SPAN_S = 120.0
#: At most this many 2 s dead-reckoning segments (every 10 s, or sparser in long sessions).
MAX_DR_SEGMENTS = 30


def middle_span(s: PreparedSession, span_s: float, delta: float) -> PreparedSession:
    """The session restricted to ``span_s`` seconds of mocap time around its middle (the whole
    session if it is shorter); ``delta``: mocap minus IMU time."""
    if s.tau[-1] - s.tau[0] <= span_s:
        return s
    mid = 0.5 * (s.tau[0] + s.tau[-1])
    lo, hi = mid - 0.5 * span_s, mid + 0.5 * span_s
    m = (s.tau >= lo) & (s.tau <= hi)
    u_lo, u_hi = np.searchsorted(s.u, [lo - delta - 1.0, hi - delta + 1.0])
    i = slice(int(u_lo), int(u_hi))
    keep = (s.removed_tau >= lo) & (s.removed_tau <= hi)
    return replace(s, u=s.u[i], gyro=s.gyro[i], accel=s.accel[i], tau=s.tau[m],
                   R_WM=s.R_WM[m], p_WM=s.p_WM[m], removed_tau=s.removed_tau[keep])


def calibration_extras(result: CalibrationResult) -> CalibrationExtras:
    """The report's computed figures: IMU residual spectra against the noise floor (with raw
    intrinsics for comparison), per-stage spectra and dead reckoning."""
    t0 = time.perf_counter()
    ex = CalibrationExtras()
    diag = result.diagnostics
    if diag is None or diag.trace is None:
        return ex
    tr = diag.trace
    s, st = tr.session, tr.model_state
    stats = {x.name: x for x in result.stages}
    for name, series in diag.residuals.items():
        if name in stats:
            sp = stage_spectrum(series, stats[name])
            if sp is not None:
                ex.stage_spectra[name] = sp
    sub = middle_span(s, SPECTRUM_SPAN_S, st.delta)
    ex.spectrum_span_s = (float(sub.tau[0]), float(sub.tau[-1]))
    pred = predict_imu(sub, st)
    if len(pred.u) > 64:
        ex.imu_analysis = analyse_residuals(sub, st, tr.noise_used, pred=pred)
        raw = replace(st, bias=np.zeros_like(st.bias),
                      effects={k: EFFECTS[k].zero() for k in st.effects})
        g0, a0 = model_forward(raw, pred.w, pred.f, pred.u)
        gb = _welch(pred.u, pred.gyro_meas - g0, 1024)
        ab = _welch(pred.u, pred.accel_meas - a0, 1024)
        if gb is not None and ab is not None:
            ex.imu_before = (gb[0], gb[1], ab[1])
    every = max(10.0, float(s.tau[-1] - s.tau[0]) / MAX_DR_SEGMENTS)
    ex.dead_reckoning = dead_reckoning(s, st, every=every)
    ex.seconds = time.perf_counter() - t0
    return ex


def write_report(path: Path, title: str, sections: Sequence[Section], inputs: Sequence[Path | None],
                 clock: RunClock, subtitle: str = "",
                 verdict: tuple[str, str] | None = None) -> Path:
    """Render the page with its provenance and write it (atomically; a one-line error if the
    file cannot be written)."""
    prov: Provenance = provenance(inputs, clock)
    return save_text(path, render_html(title, sections, prov, subtitle, verdict))


def calibration_verdict(result: CalibrationResult) -> tuple[str, str] | None:
    """The plausibility verdict as a badge (text, ok/bad)."""
    if result.plausibility is None:
        return None
    v = result.plausibility.verdict
    return (f"plausibility: {v}", "ok" if v == "plausible" else "bad")


def _every_take(sections: list[Section], result: CalibrationResult,
                title: str = "") -> list[Section]:
    """With several takes, the sections drawn from the solver's series (residuals,
    trajectory) are the first take's: say so, and add every other take's (titles after
    ``title``, the prefix the page gives the result's sections)."""
    from mocap_calib.report.html import take_sections

    others = result.diagnostics.takes[1:] if result.diagnostics else []
    if not others:
        return sections
    out = [replace(s, title=f"{title}Take 1: {s.title.removeprefix(title)}")
           if s.id in ("sec-residuals", "sec-trajectory") else s for s in sections]
    for k, d in enumerate(others, start=2):
        view = replace(result, diagnostics=d)
        out += [replace(s, title=title + s.title)
                for s in take_sections(view, k, calibration_extras(view))]
    return out


def write_calibration_html(path: Path, result: CalibrationResult, inputs: Sequence[Path | None],
                           clock: RunClock) -> Path:
    """The ``calibrate --html`` page."""
    from mocap_calib.report.html import calibration_sections

    sections = _every_take(calibration_sections(result, calibration_extras(result)), result)
    sub = (f"model {result.model}; {result.session.get('duration_s', '?')} s of session, "
           f"{result.session.get('imu_samples', '?')} IMU samples, "
           f"{result.session.get('mocap_samples', '?')} mocap poses")
    return write_report(path, "mocap-calib calibration report", sections, inputs, clock, sub,
                        calibration_verdict(result))


def write_diagnosis_html(path: Path, report, inputs: Sequence[Path | None],
                         clock: RunClock) -> Path:
    """The ``diagnose --html`` page: the steps, then the final calibration's sections."""
    from mocap_calib.report.html import diagnosis_sections

    sections = _every_take(diagnosis_sections(report, calibration_extras(report.final)),
                           report.final, "Final calibration: ")
    clean = not report.found and not getattr(report, "unexplained", None)
    verdict = (f"diagnosis: {report.verdict}", "ok" if clean else "warn")
    sub = f"start model {report.start_model}, final model {report.final_model}"
    return write_report(path, "mocap-calib model diagnosis report", sections, inputs, clock, sub,
                        verdict)


def write_batch_report(path: Path | str, sessions: Sequence[dict], fleet: dict | None,
                       clock: RunClock | None = None) -> Path:
    """The ``batch --html`` page: ``sessions`` are the batch file's entries (``result``: the
    session's result YAML relative to the page's folder), ``fleet`` the fleet summary's plain
    data (None: none). Results that cannot be read are listed without numbers."""
    from mocap_calib.errors import CalibrationError, Interrupted
    from mocap_calib.io.yaml_io import load_result
    from mocap_calib.report.html import batch_sections

    path = Path(path)
    results, files = {}, []
    for s in sessions:
        rel = s.get("result")
        if not rel:
            continue
        f = path.parent / rel
        try:
            results[str(s.get("id"))] = load_result(f)
            files.append(f)
        except Interrupted:
            raise
        except (CalibrationError, OSError):
            continue
    n = len(sessions)
    sub = f"{n} sessions, {len(results)} results, {n - len(results)} without"
    verdict = ("all sessions calibrated", "ok") if len(results) == n else (
        f"{n - len(results)} of {n} sessions without a result", "warn")
    return write_report(path, "mocap-calib batch report", batch_sections(sessions, results, fleet),
                        files, clock or RunClock(), sub, verdict)
