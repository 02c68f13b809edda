"""A rerun recording (``.rrd``) of a calibration, for judging it by eye.

It draws a result and the series computed with it
(:class:`~mocap_calib.core.result.series.OutputSeries`); it computes none of them.

Everything is on the timeline ``t``: mocap time in seconds since the mocap origin (``tau``; an
IMU sample at IMU time ``u`` is shown at ``u + delta``).
Solver iterations are on the sequence timeline ``iteration``. Entity paths:

- ``world/mocap/trajectory``: marker path ``p_WM`` (static strips, split at mocap gaps).
- ``world/marker``, ``world/imu``: ``T_WM`` and ``T_WI = T_WM T_MI`` over time, with axes.
- ``world/imu/lever``: IMU origin to marker origin, i.e. ``p_MI`` (static).
- ``world/gravity``: estimated gravity direction next to the mocap -z axis (static arrows).
- ``world/dead_reckoning/<mocap|before|after>``: 2 s IMU dead-reckoning segments, and
  ``dead_reckoning/<before|after>/<position|attitude>_error`` their errors at the end.
- ``residuals/<stage>/<before|after>/<x|y|z>``, ``residuals/<stage>/weight``: stage residuals
  (complete series) and robust weights; ``residuals/position/rotation/<before|after>/<x|y|z>``
  the position stage's attitude part (deg).
- ``imu/<gyro|accel>/<measured|predicted|difference>/<x|y|z>``: raw IMU vs the prediction.
- ``solver/<cost|time_offset|gravity_tilt>``, ``solver/<p_MI|R_MI|gyro_bias|accel_bias>/<x|y|z>``:
  position-stage iterates on ``iteration``.
- ``diagnose/<step>/<stage>/...``: optional extra residual series, laid out like ``residuals``.
- ``imu_gaps/gap_<k>``: one span per IMU gap of the session, from the last sample before it
  to the first after it (mocap time), drawn as a thick bar on the zero line of every time
  plot; its legend name says its length and whether it was bridged or split the session. At
  most :data:`MAX_GAP_SPANS` are drawn.
- ``takes/<k>/...``: with several takes, the second take on: its own ``world``,
  ``dead_reckoning``, ``residuals``, ``imu`` and ``imu_gaps`` as above (its time on its own
  mocap clock), each in a tab "take k"; the paths above are the first take's.
- ``summary`` (:func:`mocap_calib.report.text.summary_table`), ``checks`` (clock search,
  plausibility, segment consistency, noise sensitivity), ``guide``: text documents.

The 3D poses are decimated to at most :data:`POSE_RATE_HZ` (by picking samples) and the IMU
signals to :data:`IMU_RATE_HZ` (by block means, which also low-pass their noise), which keeps a
10-minute session under 30 MB; residual series are complete.
Only this package imports rerun, and only when a recording is written.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.policy import IMU_BRIDGE_MAX_S
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.result.series import (
    DeadReckoning,
    ImuPrediction,
    OutputSeries,
    ResidualSeries,
    Scene,
    SolverHistory,
    TakeSeries,
)
from mocap_calib.errors import InputError
from mocap_calib.report.text import checks_lines, summary_table
from mocap_calib.viz._rerun import (
    AXIS_RGB,
    GRAY,
    IMU_GAPS,
    ITERATION,
    TIMELINE,
    Logger,
    default_blueprint,
)

Array = NDArray[np.float64]

#: Highest rate (Hz) of the 3D poses in a recording.
POSE_RATE_HZ = 50.0
#: Highest rate (Hz) of the IMU signal series: block means, which low-pass the raw signals to
#: about the 10 Hz bandwidth of the prediction from (low-passed) mocap poses.
IMU_RATE_HZ = 25.0
#: Most IMU gap spans drawn (a log with more is summarised by the first ones).
MAX_GAP_SPANS = 200
#: Colours of the gap spans: bridged, split.
GAP_RGB = ((250, 150, 30), (150, 40, 160))

_GUIDE = """\
# How to read this recording

* **Timeline `t`**: mocap time (s since the mocap origin). IMU samples are shown at their
  mocap time (IMU stamp + estimated clock offset). Switch to the **`iteration`** timeline for
  `solver/...` (the position stage's iterates).
* **3D (`world/`)**: grey = marker path; `world/marker` and `world/imu` are the marker and
  the IMU frame (placed by the estimated T_MI); the line `world/imu/lever` joins them.
  `world/gravity`: estimated gravity direction next to the mocap -z axis.
* **Dead reckoning** (`world/dead_reckoning`): every 10 s the IMU is integrated for 2 s from
  the mocap state (attitude, position, velocity of the IMU origin). *before* = raw IMU
  (zero biases, no effects), *after* = the calibrated model; both use the estimated T_MI,
  gravity and clock offset. *mocap* = where the IMU really went. After should stay on it.
* **Residuals**: *before* = at the stage's start values, *after* = at its solution; the RMS
  of *after* equals the stage's `rms_after` in the result. Spikes with a low `weight` were
  down-weighted as outliers.
* **IMU**: measured raw gyro/accel vs what the calibrated model predicts from the mocap
  (block means at about 25 Hz); the difference should be noise around zero.
* **IMU gaps** (`imu_gaps/`): thick bars on the zero line of every time plot, orange where a
  gap was bridged, purple where it split the session; nothing is integrated across them.
"""


# ---------------------------------------------------------------------------- public API
def write_calibration_recording(path: str | Path, result: CalibrationResult,
                                series: OutputSeries) -> Path:
    """Write a rerun recording of a calibration (see the module docstring for its contents).

    Args:
        path: the ``.rrd`` file to write (parent folders are created), directly: to replace a
            file whole, write a temporary one and rename it (``io.atomic.write_with``).
        result: the calibration (its summary and checks).
        series: what the recording draws, computed for it
            (``core.diagnosis.outputs.output_series(result, recording=True, ...)``): each
            take's scene, IMU prediction, dead reckoning and residuals, the solver's iterates,
            and the diagnosis steps' series, logged under ``diagnose/<label>/<stage>/...``
            like ``residuals/`` (labels are reduced to ``[A-Za-z0-9_.-]``; a repeated label
            gets a ``_2``... suffix).

    Returns:
        The written path.

    Raises:
        InputError: ``path`` is a folder.
        OSError: the file cannot be written (``io.atomic.write_with`` makes it one line).
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder; give a file name for the recording, e.g. "
                         "calib.rrd")
    first = series.first or TakeSeries()
    residuals = first.residuals
    steps = _named_steps(series.steps)
    pos = residuals.get("position")
    spans = _imu_gaps(first)
    # With several takes, the second on: their own scene, series and residuals.
    others = [(k, t) for k, t in enumerate(series.takes[1:], start=2) if t.scene is not None]
    blueprint = default_blueprint(list(residuals), pos is not None and pos.rotation_after
                                  is not None, [(n, list(x)) for n, x in steps],
                                  series.solver is not None, has_imu_gaps=len(spans) > 0,
                                  other_takes=[(k, len(_imu_gaps(t)) > 0) for k, t in others])

    # rerun's writer writes ``path`` itself: the workflows give it a temporary file that
    # mocap_calib.io.atomic renames into place (no half-written recording).
    path.parent.mkdir(parents=True, exist_ok=True)
    log = Logger(str(path), blueprint, name=f"mocap-calib {result.model}")
    try:
        log.log("world", log.rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        log.text("summary", summary_table(result))
        log.text("checks", "\n".join(checks_lines(result)) or "no checks were run")
        log.text("guide", _GUIDE, markdown=True)
        _log_take(log, first)
        _log_solver(log, series.solver)
        for k, take in others:
            _log_take(log.at(f"takes/{k}"), take)
        for name, series_by_stage in steps:
            for stage, res in series_by_stage.items():
                _log_residuals(log, f"diagnose/{name}/{stage}", res)
    finally:
        log.close()
    return path


def _log_take(log: Logger, take: TakeSeries) -> None:
    """One take's scene, dead reckoning, residuals, IMU series and gaps."""
    if log.prefix:
        log.log("world", log.rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    if take.scene is not None:
        _log_world(log, take.scene)
    _log_dead_reckoning(log, take.dead_reckoning)
    for stage, series in take.residuals.items():
        _log_residuals(log, f"residuals/{stage}", series)
    if take.scene is not None and take.imu is not None:
        _log_imu(log, take.imu, take.scene)
    _log_imu_gaps(log, _imu_gaps(take))


def _imu_gaps(take: TakeSeries) -> Array:
    """(G, 2) the take's IMU gaps on the mocap clock (none without a scene)."""
    return take.scene.imu_gaps if take.scene is not None else np.zeros((0, 2))


def _stride(rate: float, max_rate: float) -> int:
    """Decimation factor that brings ``rate`` to at most ``max_rate``."""
    return max(1, int(np.ceil(rate / max_rate - 1e-9)))


def _block_means(x: Array, segments: Sequence[NDArray[np.int64]], k: int) -> Array:
    """Means of ``k`` consecutive rows, within each segment (a partial last block is dropped)."""
    out = []
    for seg in segments:
        n = len(seg) // k
        if n:
            out.append(x[seg[:n * k]].reshape(n, k, *x.shape[1:]).mean(axis=1))
    return np.concatenate(out) if out else np.zeros((0, *x.shape[1:]))


def _named_steps(steps: Sequence[tuple[str, Mapping[str, ResidualSeries]]]
                 ) -> list[tuple[str, Mapping[str, ResidualSeries]]]:
    """Entity-safe, unique step names."""
    out: list[tuple[str, Mapping[str, ResidualSeries]]] = []
    seen: set[str] = set()
    for label, series in steps:
        base = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(label)).strip("_") or "step"
        name, n = base, 1
        while name in seen:
            n += 1
            name = f"{base}_{n}"
        seen.add(name)
        out.append((name, series))
    return out


# ---------------------------------------------------------------------------- logging
def _quat_xyzw(R: Array) -> Array:
    return so3.rotmat_to_quat(R)[:, [1, 2, 3, 0]]


def _log_world(log: Logger, s: Scene) -> None:
    """Marker path, marker and IMU frames over time, lever arm, gravity."""
    rr = log.rr
    k = _stride(s.mocap_rate, POSE_RATE_HZ)
    idx = np.arange(0, len(s.tau), k)
    tau, R_WM, p_WM = s.tau[idx], s.R_WM[idx], s.p_WM[idx]
    R_WI = R_WM @ s.R_MI
    p_WI = p_WM + R_WM @ s.p_MI

    # Path, split at mocap gaps (a gap between two kept samples breaks the strip): the
    # number of gaps before each kept sample.
    gaps = np.searchsorted(s.gap_index, idx, side="left")
    strips = [p_WM[gaps == g] for g in np.unique(gaps)]
    strips = [x for x in strips if len(x) > 1]
    extent = float(np.max(np.ptp(s.p_WM, axis=0))) if len(s.p_WM) else 1.0
    axis_len = float(np.clip(0.05 * extent, 0.05, 0.3))
    log.log("world/mocap/trajectory",
            rr.LineStrips3D(strips, colors=[GRAY], radii=rr.components.Radius.ui_points(1.0)),
            static=True)

    time = [rr.TimeColumn(TIMELINE, duration=tau)]
    log.send_columns("world/marker", indexes=time,
                     columns=rr.Transform3D.columns(translation=p_WM,
                                                    quaternion=_quat_xyzw(R_WM)))
    log.send_columns("world/imu", indexes=time,
                     columns=rr.Transform3D.columns(translation=p_WI,
                                                    quaternion=_quat_xyzw(R_WI)))
    log.log("world/marker", rr.TransformAxes3D(axis_len), static=True)
    log.log("world/imu", rr.TransformAxes3D(0.6 * axis_len), static=True)
    p_IM = -s.R_MI.T @ s.p_MI  # marker origin in the IMU frame
    log.log("world/imu/lever",
            rr.LineStrips3D([[np.zeros(3), p_IM]], colors=[(255, 200, 0)],
                            labels=[f"T_MI lever {1e3 * np.linalg.norm(s.p_MI):.1f} mm"]),
            static=True)

    g_dir = s.g_W / np.linalg.norm(s.g_W)
    tilt = float(np.degrees(np.arccos(np.clip(-g_dir[2], -1.0, 1.0))))
    L = max(0.3 * extent, 0.2)
    centre = np.mean(s.p_WM, axis=0)
    log.log("world/gravity",
            rr.Arrows3D(vectors=[L * g_dir, [0.0, 0.0, -L]], origins=[centre, centre],
                        colors=[(255, 140, 0), GRAY],
                        labels=[f"gravity (tilt {tilt:.2f} deg)", "mocap -z"]),
            static=True)


def _log_dead_reckoning(log: Logger, dr: DeadReckoning | None) -> None:
    """Segments as strips at their start time, and their end errors as series."""
    if dr is None:
        return
    rr = log.rr
    t0 = dr.tau[:, 0]
    n = len(t0)
    time = [rr.TimeColumn(TIMELINE, duration=t0)]
    parts = (("mocap", dr.p_ref, GRAY, "mocap"),
             ("before", dr.p_before, AXIS_RGB[0], "raw IMU"),
             ("after", dr.p_after, AXIS_RGB[2], "calibrated IMU"))
    for name, p, color, label in parts:
        log.send_columns(
        f"world/dead_reckoning/{name}", indexes=time,
        columns=rr.LineStrips3D.columns(strips=list(p), colors=[color] * n,
                                        labels=[label] * n,
                                        radii=[rr.components.Radius.ui_points(2.0)] * n))
    for which, color in (("before", AXIS_RGB[0]), ("after", AXIS_RGB[2])):
        path = f"dead_reckoning/{which}/position_error"
        log.style(path, f"{which}: position error after {dr.length_s:g} s [m]", color)
        log.scalars(path, t0, dr.position_error(which))
        path = f"dead_reckoning/{which}/attitude_error"
        log.style(path, f"{which}: attitude error after {dr.length_s:g} s [deg]", color)
        log.scalars(path, t0, dr.attitude_error(which))


def _log_residuals(log: Logger, prefix: str, series: ResidualSeries) -> None:
    """Complete before/after series per axis, the weights, and the rotation part if any."""
    unit = series.unit
    log.xyz(f"{prefix}/before", series.t, series.before, "before", unit, pale=True, width=1.0)
    log.xyz(f"{prefix}/after", series.t, series.after, "after", unit)
    log.style(f"{prefix}/weight", f"{prefix.rsplit('/', 1)[-1]} weight", GRAY)
    log.scalars(f"{prefix}/weight", series.t, series.weight)
    if series.rotation_before is not None:
        log.xyz(f"{prefix}/rotation/before", series.t, series.rotation_before, "before", "deg",
                pale=True, width=1.0)
    if series.rotation_after is not None:
        log.xyz(f"{prefix}/rotation/after", series.t, series.rotation_after, "after", "deg")


def _log_imu(log: Logger, pred: ImuPrediction, s: Scene) -> None:
    """Measured vs predicted raw IMU signals and their difference, as block means."""
    if len(pred.u) == 0:
        return
    k = _stride(s.imu_rate, IMU_RATE_HZ)
    tau = _block_means(pred.u, pred.segments, k) + s.delta
    for sensor, meas, model, unit in (("gyro", pred.gyro_meas, pred.gyro_pred, "rad/s"),
                                      ("accel", pred.accel_meas, pred.accel_pred, "m/s^2")):
        mm = _block_means(meas, pred.segments, k)
        pm = _block_means(model, pred.segments, k)
        log.xyz(f"imu/{sensor}/measured", tau, mm, f"{sensor} measured", unit, width=1.0)
        log.xyz(f"imu/{sensor}/predicted", tau, pm, f"{sensor} predicted", unit, pale=True,
                width=2.5)
        log.xyz(f"imu/{sensor}/difference", tau, mm - pm, f"{sensor} measured - predicted", unit)


def _log_imu_gaps(log: Logger, spans: Array) -> None:
    """One two-point series per gap on the zero line, thick, coloured by what was done."""
    for k, (a, b) in enumerate(spans[:MAX_GAP_SPANS]):
        split = b - a > IMU_BRIDGE_MAX_S
        path = f"{IMU_GAPS}/gap_{k:03d}"
        log.style(path, f"IMU gap {k + 1}: {b - a:.3f} s, {'split' if split else 'bridged'}",
                  GAP_RGB[int(split)], width=8.0)
        log.scalars(path, np.array([a, b]), np.zeros(2))


def _log_solver(log: Logger, h: SolverHistory | None) -> None:
    """Position-stage iterates on the ``iteration`` timeline."""
    if h is None:
        return
    it = h.iteration
    g = h.g_dir / np.linalg.norm(h.g_dir, axis=1, keepdims=True)
    scalars = {
        "cost": (h.cost, "cost (LM error)"),
        "time_offset": (1e3 * (h.delta - h.clock_shift), "time offset [ms]"),
        "gravity_tilt": (np.degrees(np.arccos(np.clip(-g[:, 2], -1.0, 1.0))),
                         "gravity tilt from mocap -z [deg]"),
    }
    for key, (values, name) in scalars.items():
        log.style(f"solver/{key}", name, (200, 120, 0))
        log.scalars(f"solver/{key}", it, values, timeline=ITERATION, sequence=True)
    vectors = {
        "p_MI": (1e3 * h.p_MI, "p_MI", "mm"),
        "R_MI": (np.degrees(so3.log(h.R_MI)), "R_MI rotation vector", "deg"),
        "gyro_bias": (h.gyro_bias, "gyro bias (mean)", "rad/s"),
        "accel_bias": (h.accel_bias, "accel bias (mean)", "m/s^2"),
    }
    for key, (values, label, unit) in vectors.items():
        log.xyz(f"solver/{key}", it, values, label, unit, timeline=ITERATION, sequence=True)
