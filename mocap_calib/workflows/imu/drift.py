"""``mocap-calib drift``: read an IMU log, a calibration (a ``calibrate`` result or ``multipos``
intrinsics) and optionally mocap poses, run the attitude-drift check over a segment, and write
its figures."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.intrinsics.attitude_drift import (
    AttitudeDriftResult,
    GyroCalibration,
    attitude_drift_check,
    reference_on_imu_times,
)
from mocap_calib.core.intrinsics.multipos.result import KIND as INTRINSICS_KIND
from mocap_calib.core.intrinsics.multipos.result import VERSION as INTRINSICS_VERSION
from mocap_calib.core.intrinsics.multipos.units import RawConversion
from mocap_calib.core.model import so3
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.core.params import group, param
from mocap_calib.core.policy import GAP_FACTOR, gap_threshold
from mocap_calib.core.versioned import KindError, check_kind
from mocap_calib.errors import InputError
from mocap_calib.io.formats.bags import RecordingOptions
from mocap_calib.io.formats.mocap_exports import ExportOptions
from mocap_calib.io.loader import load_inputs
from mocap_calib.io.result_files import describe_kind, file_kind
from mocap_calib.io.yaml_io import load_result, load_yaml, save_yaml
from mocap_calib.report.intrinsics_text import drift_summary
from mocap_calib.workflows.imu.imu_input import ImuSpec, ProgressFn, say
from mocap_calib.workflows.outputs import OutputPlan, Product, output, write_products
from mocap_calib.workflows.session import MocapFormat

Array = NDArray[np.float64]

_CALIB_FIX = ("pass a result of 'mocap-calib calibrate' or intrinsics of 'mocap-calib "
              "multipos'")


@dataclass
class DriftCalibration:
    """A calibration file turned into what the drift check needs.

    Attributes:
        kind: ``calibrate`` (a mocap calibration result) or ``multipos`` (intrinsics).
        calibration: the gyro (and accel) corrections.
        R_MI: rotation of ``T_marker_imu`` (calibrate results), else None.
        gravity_dir: ``gravity_in_mocap`` (calibrate results), else None.
        time_offset: clock offset ``t_d`` in s (0 when not given).
        gyro_bias_rate: ``r_g`` of ``gyro_bias_drift`` in rad/s^2, or None.
        session_span_ns: (first, last) IMU stamp of the calibration's session, when known.
        raw_input: for intrinsics of raw counts, their conversion to the readings the
            calibration is for (the IMU log must then be raw counts too).
    """

    kind: str
    calibration: GyroCalibration
    R_MI: Array | None = None
    gravity_dir: Array | None = None
    time_offset: float = 0.0
    gyro_bias_rate: Array | None = None
    session_span_ns: tuple[int, int] | None = None
    raw_input: RawConversion | None = None


def _vec(value: Any, shape: tuple[int, ...], path: Path, name: str) -> Array | None:
    if value is None:
        return None
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = np.zeros(0)
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise InputError(f"{path}: '{name}' must be {shape} finite numbers; {_CALIB_FIX}")
    return arr


def _from_calibrate_result(path: Path) -> DriftCalibration:
    res = load_result(path)  # checks version and keys
    if res.gyro_bias is None:
        raise InputError(f"{path}: the gyro bias is null (unobservable in that session); "
                         "the drift check needs it")
    values: dict[str, Any] = {"gyro_bias": res.gyro_bias, "accel_bias": res.accel_bias}
    rate = None
    for name, rec in (res.effects or {}).items():
        if not isinstance(rec, Mapping):
            continue
        for key in ("gyro_matrix", "g_sensitivity", "accel_matrix"):
            if rec.get(key) is not None:
                values[key] = _vec(rec[key], (3, 3), path, f"effects.{name}.{key}")
        if rec.get("gyro_bias_rate") is not None:
            rate = _vec(rec["gyro_bias_rate"], (3,), path, f"effects.{name}.gyro_bias_rate")
    R_MI = None
    if res.rotation_wxyz is not None:
        q = _vec(res.rotation_wxyz, (4,), path, "T_marker_imu.rotation_wxyz")
        assert q is not None
        R_MI = so3.quat_to_rotmat(q / np.linalg.norm(q))
    g = _vec(res.gravity_in_mocap, (3,), path, "gravity_in_mocap")
    span = None
    start, dur = res.session.get("imu_start_ns"), res.session.get("duration_s")
    if isinstance(start, int) and isinstance(dur, int | float):
        span = (start, start + int(round(float(dur) * 1e9)))
    return DriftCalibration("calibrate", GyroCalibration.from_dict(values), R_MI,
                            None if g is None else g / np.linalg.norm(g),
                            float(res.time_offset or 0.0), rate, span)


def _from_intrinsics(path: Path, data: dict[str, Any]) -> DriftCalibration:
    try:
        check_kind(data, INTRINSICS_KIND, INTRINSICS_VERSION)
    except KindError as err:
        raise InputError(f"{path}: {err}") from None
    values = {}
    for name, shape in (("accel_matrix", (3, 3)), ("accel_bias", (3,)),
                        ("gyro_matrix", (3, 3)), ("gyro_bias", (3,)), ("g_sensitivity", (3, 3))):
        values[name] = _vec(data.get(name), shape, path, name)
    raw = None
    if data.get("raw_input") is not None:
        try:
            raw = RawConversion.from_dict(data["raw_input"])
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"{path}: malformed 'raw_input' ({err}); {_CALIB_FIX}") from None
    if values["gyro_bias"] is None:
        raise InputError(f"{path}: no 'gyro_bias'; {_CALIB_FIX}")
    span = None
    diag = data.get("diagnostics")
    if isinstance(diag, dict) and isinstance(diag.get("session_time_ns"), int):
        iv = np.asarray(diag.get("static_intervals_s") or [[0.0, 0.0]], dtype=float)
        t0 = int(diag["session_time_ns"])
        span = (t0, t0 + int(round(float(np.max(iv)) * 1e9)))
    return DriftCalibration("multipos", GyroCalibration.from_dict(values), session_span_ns=span,
                            raw_input=raw)


def read_calibration(path: Path | str) -> DriftCalibration:
    """Read a calibrate result or multipos intrinsics YAML for the drift check.

    Raises:
        InputError: missing file, another kind of file, or malformed entries.
    """
    path = Path(path)
    data = load_yaml(path, "calibration file")
    kind = file_kind(data)
    if kind == "calibration":
        return _from_calibrate_result(path)
    if kind == "intrinsics":
        return _from_intrinsics(path, data)
    if kind is None:
        raise InputError(f"{path}: not a calibration (no 'T_marker_imu' or 'gyro_matrix'); "
                         f"{_CALIB_FIX}")
    raise InputError(f"{path}: is {describe_kind(kind)}, not a calibration; {_CALIB_FIX}")


@dataclass
class DriftRun:
    """An attitude-drift check and what it was computed from.

    Attributes:
        result: roll/pitch/tilt drift raw and calibrated.
        calibration: the calibration file read.
        calibration_file: its path.
        notes: one-line notes.
        written: files written.
    """

    result: AttitudeDriftResult
    calibration: DriftCalibration
    calibration_file: Path
    notes: list[str] = field(default_factory=list)
    written: list[Path] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        d = self.result.to_dict()
        d["calibration"] = {"file": str(self.calibration_file), "kind": self.calibration.kind}
        d["notes"] = list(self.notes)
        return d

    def summary(self) -> str:
        """Roll, pitch and tilt drift before/after and the reduction."""
        return drift_summary(self.result, str(self.calibration_file), self.calibration.kind,
                             self.notes)


def _check_segment_options(start: float, end: float, static_window_s: float) -> None:
    if not (np.isfinite(start) and np.isfinite(end)):
        raise InputError("--segment-start and --segment-end must be finite times in s")
    if not start < end:
        raise InputError(f"--segment-start {start:g} s must be before --segment-end {end:g} s")
    if not static_window_s > 0:
        raise InputError(f"--static-window {static_window_s:g}: must be positive")


def _refuse_gaps(imu: ImuSamples, t0: float, t1: float) -> None:
    """The gyro cannot be integrated across an IMU gap: a segment must hold none."""
    d = np.diff(imu.t)
    gaps = np.flatnonzero((d > gap_threshold(imu.t)) & (imu.t[1:] > t0) & (imu.t[:-1] < t1))
    if len(gaps):
        i = int(gaps[0])
        raise InputError(
            f"{imu.source}: the segment holds {len(gaps)} IMU gap(s), the first of "
            f"{d[i]:.3f} s at {imu.t[i] - imu.t[0]:.3f} s; the gyro cannot be integrated "
            "across a gap: choose --segment-start/--segment-end between the gaps")


def _read_streams(spec: ImuSpec, mocap: Path | None, fmt: MocapFormat,
                  progress: ProgressFn | None) -> tuple[ImuSamples, MocapPoses | None]:
    say(progress, f"reading {spec.name}" + (f" and {mocap}" if mocap is not None else ""))
    poses: MocapPoses | None = None
    if mocap is None:
        imu, read_notes = spec.load()
    else:
        imu, poses, read_notes = load_inputs(
            spec.imu, mocap, None, columns=spec.columns, time_unit=spec.time_unit,
            gyro_unit=spec.gyro_unit, accel_unit=spec.accel_unit, quat_order=fmt.quat_order,
            position_unit=fmt.position_unit,
            recording=RecordingOptions(spec.imu_topic, fmt.mocap_topic, fmt.mocap_frame,
                                       spec.stamp),
            export=ExportOptions(fmt.mocap_format, fmt.rigid_body, fmt.rotation,
                                 fmt.mocap_rate))
    for n in read_notes:
        say(progress, n)
    return imu, poses


def _at_segment(cal: DriftCalibration, seg_ns: tuple[int, int], notes: list[str]
                ) -> GyroCalibration:
    """The calibration for the segment: the gyro bias moved along its drift rate."""
    out = cal.calibration
    if cal.gyro_bias_rate is not None:
        if cal.session_span_ns is not None:
            mid_cal = 0.5 * (cal.session_span_ns[0] + cal.session_span_ns[1])
            dt = (0.5 * (seg_ns[0] + seg_ns[1]) - mid_cal) * 1e-9
            out = out.with_bias_drift(cal.gyro_bias_rate, dt)
            notes.append(f"gyro bias moved by its drift rate to the segment's middle "
                         f"({dt:+.1f} s from the calibration's)")
        else:
            notes.append("gyro_bias_rate ignored: the calibration file does not say when its "
                         "session was")
    if cal.session_span_ns is not None and (seg_ns[0] < cal.session_span_ns[1]
                                            and seg_ns[1] > cal.session_span_ns[0]):
        notes.append("the segment overlaps the session the calibration was computed from; "
                     "the check is optimistic on data the calibration has seen")
    return out


def _mocap_reference(imu: ImuSamples, poses: MocapPoses, cal: DriftCalibration, t0: float,
                     t1: float, start: float, end: float, notes: list[str]
                     ) -> dict[str, Any]:
    """Keyword arguments of the drift check for a mocap reference (IMU attitudes on IMU
    times, gravity direction)."""
    assert cal.R_MI is not None
    # Mocap times onto the IMU clock: tau = u + (origin_imu - origin_mocap) 1e-9 + t_d, as
    # core/prepare/session.py relates the clocks.
    shift = (poses.time_origin_ns - imu.time_origin_ns) * 1e-9
    t_ref = poses.t + shift - cal.time_offset
    if t_ref[0] > t0 or t_ref[-1] < t1:
        raise InputError(f"the mocap poses cover {t_ref[0] - imu.t[0]:.3f}-"
                         f"{t_ref[-1] - imu.t[0]:.3f} s after the IMU start, not the whole "
                         f"segment [{start:g}, {end:g}] s; choose a segment inside both")
    kwargs: dict[str, Any] = {"reference_series": reference_on_imu_times(
        imu.t, t_ref, poses.rotation @ cal.R_MI, t0, t1, GAP_FACTOR,
        ("--segment-start", "--segment-end"))}
    if cal.gravity_dir is not None:
        kwargs["gravity_dir"] = cal.gravity_dir
    else:
        notes.append("gravity_in_mocap is null in the calibration: mocap -z taken as down")
    return kwargs


@dataclass
class DriftRequest:
    """Everything ``drift`` can be told."""

    calibration: Path = param(MISSING, "calibration YAML: a 'calibrate' result or 'multipos' "
                              "intrinsics", metavar="PATH")
    segment_start: float = param(MISSING, "start of the segment integrated, s after the IMU "
                                 "log's first sample", unit="s", lo=0.0)
    segment_end: float = param(MISSING, "end of the segment integrated, s after the IMU log's "
                               "first sample", unit="s", lo=0.0, lo_open=True)
    imu: ImuSpec = group(ImuSpec, "Input")
    mocap: Path | None = param(
        None, "mocap poses T_WM of the same session (the reference attitude); without them the "
        "accelerometer at rest at --segment-start and --segment-end", metavar="PATH",
        show_default=False)
    poses: MocapFormat = group(MocapFormat, "Mocap")
    static_window: float = param(
        1.0, "without --mocap: window around --segment-start/--segment-end over which the "
        "accelerometer is averaged", unit="s", lo=0.0, lo_open=True, hi=600.0)
    out: Path | None = output(None, "also write the figures as YAML", metavar="PATH",
                              show_default=False)
    quiet: bool = param(False, "no progress lines", decls=("--quiet", "-q"))

    def plan(self) -> OutputPlan:
        return OutputPlan.of(self)


def run_drift(request: DriftRequest, progress: ProgressFn | None = None) -> DriftRun:
    """Attitude-drift check of a calibration over a segment of an IMU log.

    The gyro is integrated over ``[segment_start, segment_end]`` (s after the IMU log's first
    sample) raw and calibrated, from the same initial attitude; roll and pitch are compared
    with the reference at the segment's end. With ``mocap``, the attitudes are ``R_WM R_MI``
    (``R_MI`` from the calibration's ``T_marker_imu``, mocap times moved onto the IMU clock with
    its ``time_offset``, gravity along its ``gravity_in_mocap``), else roll and pitch come from
    the accelerometer, and the IMU must rest at the segment's start and end. With ``out``, the
    figures are written as YAML.

    Raises:
        InputError: bad files or options, the segment's start not before its end, segment
            outside the log, mocap with a calibration that has no ``T_marker_imu``.
        ObservabilityError: no mocap and the IMU is not at rest at the segment's start or
            end.
    """
    spec, calibration = request.imu, request.calibration
    start, end = request.segment_start, request.segment_end
    mocap, out, static_window_s = request.mocap, request.out, request.static_window
    request.plan().check()
    _check_segment_options(start, end, static_window_s)
    cal = read_calibration(calibration)
    notes: list[str] = []
    if mocap is not None and cal.R_MI is None:
        raise InputError(f"{calibration}: has no T_marker_imu, so mocap attitudes cannot be "
                         "turned into IMU attitudes; pass a 'mocap-calib calibrate' result, or "
                         "leave out --mocap to use the accelerometer at rest")
    if cal.raw_input is not None:
        if spec.gyro_unit is not None or spec.accel_unit is not None:
            raise InputError(f"{calibration}: calibrates raw counts, so the IMU log is read as "
                             "raw counts; leave out --gyro-unit and --accel-unit")
        spec = replace(spec, raw=True)
    imu, poses = _read_streams(spec, mocap, request.poses, progress)
    if cal.raw_input is not None:
        imu = cal.raw_input.apply(imu)
        notes.append("raw counts converted with the calibration's 'raw_input'")
    if start < 0 or end > imu.duration + 1e-9:
        raise InputError(f"segment [{start:g}, {end:g}] s is outside the IMU log, which spans "
                         f"0-{imu.duration:.3f} s after its first sample; choose "
                         "--segment-start and --segment-end inside it")
    t0 = float(imu.t[0]) + start
    t1 = float(imu.t[0]) + end
    _refuse_gaps(imu, t0, t1)
    stamps = imu.stamps_ns()
    seg_ns = (int(stamps[0]) + int(round(start * 1e9)), int(stamps[0]) + int(round(end * 1e9)))
    gyro_cal = _at_segment(cal, seg_ns, notes)
    kwargs: dict[str, Any] = {"static_window_s": static_window_s}
    if poses is not None:
        kwargs.update(_mocap_reference(imu, poses, cal, t0, t1, start, end, notes))
    say(progress, f"integrating the gyro over [{start:g}, {end:g}] s, raw and calibrated")
    result = attitude_drift_check(
        imu, t0, t1, gyro_cal,
        not_at_rest_fix="pass --mocap or move --segment-start/--segment-end to where the IMU "
        "rests", **kwargs)
    # Report times relative to the log's first sample, as the options are given.
    result = replace(result, t0=result.t0 - float(imu.t[0]), t1=result.t1 - float(imu.t[0]),
                     series_t=result.series_t - float(imu.t[0]))
    run = DriftRun(result, cal, Path(calibration), notes)
    written = write_products([None if out is None else Product(
        "--out", out, lambda: save_yaml(out, run.to_dict(), "mocap-calib attitude-drift check "
                                        "(deg, s)."))])
    run.written = [p.path for p in written]
    return run
