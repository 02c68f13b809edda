"""The series the outputs draw (:class:`~mocap_calib.core.result.series.OutputSeries`), computed
once after the fit from the result and its diagnostics.

Only what the requested outputs draw is computed: the recording's IMU prediction over each take
and its dead reckoning every 10 s, the report's residual spectra against the noise floor and its
dead reckoning (at most :data:`MAX_DR_SEGMENTS` segments); where both outputs ask for the same
series it is computed once. A run that writes neither does not call this module.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from mocap_calib.core.clock.search import MIN_PEAK_Z, ClockSearch
from mocap_calib.core.diagnosis.dead_reckoning import DR_EVERY_S, dead_reckoning
from mocap_calib.core.diagnosis.predict import analyse_residuals, model_forward, predict_imu
from mocap_calib.core.model.effects import EFFECTS
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.core.prepare.session import PreparedSession, prepare
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.result.series import (
    ClockCurve,
    DeadReckoning,
    ImuPrediction,
    OutputSeries,
    ReportFigures,
    Scene,
    SolverHistory,
    StageSpectrum,
    TakeSeries,
)
from mocap_calib.core.result.state import CalibrationTrace, ModelState
from mocap_calib.core.stages.figures import ResidualSeries, StageStats

if TYPE_CHECKING:
    from mocap_calib.core.diagnosis.report import DiagnoseReport

Array = NDArray[np.float64]

#: The IMU-domain spectra use at most this much of the session (its middle), so that the report
#: stays cheap for long sessions; a few minutes give Welch estimates with dozens of averages.
SPECTRUM_SPAN_S = 120.0
#: At most this many 2 s dead-reckoning segments in the report (every 10 s, or sparser in long
#: sessions).
MAX_DR_SEGMENTS = 30


def output_series(result: CalibrationResult, *, recording: bool = False, report: bool = False,
                  imu: ImuSamples | None = None, mocap: MocapPoses | None = None,
                  steps: Sequence[tuple[str, Mapping[str, ResidualSeries]]] = ()
                  ) -> OutputSeries:
    """The series the requested outputs draw.

    Args:
        result: the calibration; with ``result.diagnostics`` (as the pipeline returns it) the
            series are those of the session, model state and residuals the solver used.
        recording: compute what the rerun recording draws. Without diagnostics its first take
            is the session prepared again from ``imu``/``mocap`` with the result's values
            (constant biases), without residual and solver series.
        report: compute what the HTML report draws (only with the solver's session).
        imu, mocap: what the calibration read (needed by a recording without diagnostics).
        steps: the diagnosis steps' series (:func:`diagnosis_steps`), for the recording.

    Raises:
        InputError: a recording without diagnostics, and the result lacks a value.
        ValueError: a recording without diagnostics, and no ``imu``/``mocap`` given.
    """
    diag = result.diagnostics
    stats = {x.name: x for x in result.stages}
    every_take = [diag, *diag.takes[1:]] if diag is not None else []
    takes = [_take(d.residuals, d.trace, stats, recording, report) for d in every_take]
    trace = diag.trace if diag is not None else None
    clock_shift = trace.session.clock_shift if trace is not None else 0.0
    if recording and trace is None:
        if imu is None or mocap is None:
            raise ValueError("a recording of a result without diagnostics needs its imu and "
                             "mocap")
        s = prepare(imu, mocap, noise=result.noise)
        st = result.model_state(s)
        residuals = diag.residuals if diag is not None else {}
        takes[:1] = [TakeSeries(dict(residuals), _scene(s, st, from_solver=False),
                                predict_imu(s, st), dead_reckoning(s, st))]
        clock_shift = s.clock_shift
    return OutputSeries(
        takes=tuple(takes),
        solver=(_solver_history(diag.iterations, clock_shift)
                if recording and diag is not None and diag.iterations else None),
        clock=_clock_curve(trace.clock) if trace is not None else None,
        steps=tuple(steps) if recording else ())


def diagnosis_series(report: DiagnoseReport, *, recording: bool = False, html: bool = False,
                     imu: ImuSamples | None = None, mocap: MocapPoses | None = None
                     ) -> OutputSeries:
    """:func:`output_series` of a diagnosis' final calibration, with every step's series."""
    return output_series(report.final, recording=recording, report=html, imu=imu, mocap=mocap,
                         steps=diagnosis_steps(report) if recording else ())


def diagnosis_steps(report: DiagnoseReport) -> list[tuple[str, dict[str, ResidualSeries]]]:
    """Residual series of every diagnosis step: the low-band measured-minus-predicted gyro and
    accel, and the position-factor innovations."""
    out = []
    for i, step in enumerate(report.steps):
        series: dict[str, ResidualSeries] = {}
        ra = step.residuals.analysis
        if ra is not None and len(ra.t):
            w = ra.keep.astype(float)
            series["gyro_lowpass"] = ResidualSeries(ra.t, ra.gyro_lp, ra.gyro_lp, w, "rad/s")
            series["accel_lowpass"] = ResidualSeries(ra.t, ra.accel_lp, ra.accel_lp, w, "m/s^2")
        if "position" in step.series:
            series["position"] = step.series["position"]
        label = f"{i}_{step.model}" if i < len(report.steps) - 1 else f"{i}_final_{step.model}"
        out.append((label, series))
    return out


def _take(residuals: Mapping[str, ResidualSeries], trace: CalibrationTrace | None,
          stats: Mapping[str, StageStats], recording: bool, report: bool) -> TakeSeries:
    """One take's series from the solver's trace (residuals only without one)."""
    if trace is None:
        return TakeSeries(dict(residuals))
    s, st = trace.session, trace.model_state
    pred = predict_imu(s, st) if recording else None
    dr = dead_reckoning(s, st) if recording else None
    figures = (_report_figures(residuals, trace, stats, pred, dr) if report else None)
    return TakeSeries(dict(residuals), _scene(s, st), pred, dr, figures)


def _scene(s: PreparedSession, st: ModelState, from_solver: bool = True) -> Scene:
    rem = s.removed_tau
    rem_p = (np.stack([np.interp(rem, s.tau, s.p_WM[:, a]) for a in range(3)], axis=1)
             if len(rem) else np.zeros((0, 3)))
    spans = np.zeros((0, 2)) if s.imu_gaps is None else s.imu_gaps.spans(st.delta)
    return Scene(s.tau, s.R_WM, s.p_WM, s.mocap_rate, s.imu_rate, s.gap,
                 np.flatnonzero(np.diff(s.tau) > s.gap), rem, rem_p, spans, st.R_MI, st.p_MI,
                 st.g_W, st.delta, from_solver)


def _solver_history(history: Sequence[Mapping[str, Any]], clock_shift: float) -> SolverHistory:
    def col(key: str) -> Array:
        return np.array([np.asarray(h[key], dtype=float) for h in history])

    return SolverHistory(np.array([h["iteration"] for h in history], dtype=np.int64),
                         col("cost"), col("delta"), col("g_dir"), col("p_MI"), col("R_MI"),
                         col("gyro_bias"), col("accel_bias"), clock_shift)


def _clock_curve(cs: ClockSearch | None) -> ClockCurve | None:
    if cs is None:
        return None
    return ClockCurve(cs.lags, cs.score, cs.time_offset, tuple(cs.candidates), cs.peak_z,
                      cs.margin_z, MIN_PEAK_Z)


# ---------------------------------------------------------------------------- the report's
def _report_figures(residuals: Mapping[str, ResidualSeries], trace: CalibrationTrace,
                    stats: Mapping[str, StageStats], pred_all: ImuPrediction | None,
                    dr_all: DeadReckoning | None) -> ReportFigures:
    """IMU residual spectra against the noise floor (with raw intrinsics for comparison) over
    the middle of the take, per-stage spectra and dead reckoning. ``pred_all``, ``dr_all``:
    the recording's prediction over the whole take and its dead reckoning every
    :data:`DR_EVERY_S`, reused where they are the same (None: not computed)."""
    s, st = trace.session, trace.model_state
    spectra = {}
    for name, series in residuals.items():
        if name in stats:
            sp = stage_spectrum(series, stats[name])
            if sp is not None:
                spectra[name] = sp
    sub = middle_span(s, SPECTRUM_SPAN_S, st.delta)
    pred = pred_all if pred_all is not None and sub is s else predict_imu(sub, st)
    analysis = before = None
    if len(pred.u) > 64:
        analysis = analyse_residuals(sub, st, trace.noise_used, pred=pred)
        before = _raw_spectra(st, pred)
    every = max(10.0, float(s.tau[-1] - s.tau[0]) / MAX_DR_SEGMENTS)
    dr = dr_all if dr_all is not None and every == DR_EVERY_S else dead_reckoning(
        s, st, every=every)
    return ReportFigures(spectra, analysis, before, dr, (float(sub.tau[0]), float(sub.tau[-1])))


def _raw_spectra(st: ModelState, pred: ImuPrediction) -> tuple[Array, Array, Array] | None:
    """(freq, gyro, accel) PSDs of measured minus predicted with raw intrinsics (zero biases,
    no effects)."""
    raw = replace(st, bias=np.zeros_like(st.bias),
                  effects={k: EFFECTS[k].zero() for k in st.effects})
    g0, a0 = model_forward(raw, pred.w, pred.f, pred.u)
    gb = _welch(pred.u, pred.gyro_meas - g0, 1024)
    ab = _welch(pred.u, pred.accel_meas - a0, 1024)
    if gb is None or ab is None:
        return None
    return gb[0], gb[1], ab[1]


def _welch(t: Array, x: Array, max_nperseg: int = 1024) -> tuple[Array, Array] | None:
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

