"""``mocap-calib groundtruth``: the IMU's trajectory in a gravity-aligned world on the IMU clock,
for evaluating VIO (EuRoC ``state_groundtruth_estimate0`` layout or TUM)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mocap_calib.core.groundtruth.smoother import (
    GroundTruth,
    GroundTruthCalibration,
    GroundTruthOptions,
    ground_truth,
)
from mocap_calib.core.model import so3
from mocap_calib.core.pipeline.calibrate import ProgressFn
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.errors import InputError
from mocap_calib.export.intrinsics import intrinsics_of
from mocap_calib.io.groundtruth import GT_FORMATS, sidecar_path, write_groundtruth
from mocap_calib.io.yaml_io import check_writable, load_noise, load_result
from mocap_calib.workflows.session import InputSpec, load_session

__all__ = ["GT_FORMATS", "GroundTruthRun", "run_groundtruth"]


@dataclass
class GroundTruthRun:
    """What was written and how (for the terminal)."""

    trajectory: Path
    sidecar: Path
    gt: GroundTruth
    notes: list[str]

    def summary(self) -> str:
        r = self.gt.report
        lines = [f"{r['samples_written']} IMU states written, {r['samples_left_out']} left out "
                 f"(smoothed sigma above {1e3 * r['limits']['max_position_sigma_m']:g} mm or "
                 f"{r['limits']['max_rotation_sigma_deg']:g} deg)",
                 f"median 1-sigma: {1e3 * r['sigma_position_m']['median']:.3f} mm, "
                 f"{r['sigma_rotation_deg']['median']:.4f} deg",
                 f"mocap: {r['mocap_samples_used']} samples used, "
                 f"{r['mocap_samples_rejected']} rejected, {len(r['mocap_gaps'])} gaps "
                 f"({sum(not g['bridged'] for g in r['mocap_gaps'])} not bridged)"]
        lines += [f"left out: {a:.3f}..{b:.3f} s" for a, b in r["spans_left_out_s"][:10]]
        return "\n".join(lines)


def _value(result: CalibrationResult, name: str, value: Any, source: Path) -> Any:
    if value is None:
        why = result.unobservable.get(name, "not determined")
        raise InputError(f"{source}: {name} is null ({why}); the ground truth needs it: "
                         "calibrate a session that determines it")
    return value


def calibration_for_groundtruth(result: CalibrationResult, source: Path, imu_origin_ns: int
                                ) -> GroundTruthCalibration:
    """The calibration's values in the form the core's ground truth takes."""
    intr = intrinsics_of(result.effects)
    rates = {}
    for eff, param in (("gyro_bias_drift", "gyro_bias_rate"),
                       ("accel_bias_drift", "accel_bias_rate")):
        value = (result.effects.get(eff) or {}).get(param)
        rates[param] = np.zeros(3) if value is None else np.asarray(value, dtype=float)
    t_mid = None
    if "imu_start_ns" in result.session and "duration_s" in result.session:
        t_mid = ((int(result.session["imu_start_ns"]) - imu_origin_ns) * 1e-9
                 + 0.5 * float(result.session["duration_s"]))
    q = _value(result, "rotation", result.rotation_wxyz, source)
    return GroundTruthCalibration(
        R_MI=so3.quat_to_rotmat(np.asarray(q)),
        p_MI=np.asarray(_value(result, "translation", result.translation, source)),
        gravity_dir=np.asarray(_value(result, "gravity", result.gravity_in_mocap, source)),
        gravity=float(result.gravity_magnitude),
        time_offset=float(_value(result, "time_offset", result.time_offset, source)),
        gyro_bias=np.asarray(_value(result, "gyro_bias", result.gyro_bias, source)),
        accel_bias=np.asarray(_value(result, "accel_bias", result.accel_bias, source)),
        gyro_matrix=intr.gyro_matrix, g_sensitivity=intr.g_sensitivity,
        accel_matrix=intr.accel_matrix, t_mid_s=t_mid, **rates,
        sigma_gyro_bias=(np.full(3, 1e-3) if result.sigma_gyro_bias is None
                         else np.asarray(result.sigma_gyro_bias)),
        sigma_accel_bias=(np.full(3, 2e-2) if result.sigma_accel_bias is None
                          else np.asarray(result.sigma_accel_bias)))


def run_groundtruth(spec: InputSpec, calibration: Path, out: Path, fmt: str = "euroc",
                    rate_hz: float | None = None, noise_file: Path | None = None,
                    max_position_sigma_mm: float = 2.0, max_rotation_sigma_deg: float = 0.1,
                    progress: ProgressFn | None = None) -> GroundTruthRun:
    """Read the session and the calibration, smooth, write the trajectory and its sidecar."""
    if fmt not in GT_FORMATS:
        raise InputError(f"unknown --format '{fmt}'; use euroc or tum")
    for name, v in (("--max-position-sigma-mm", max_position_sigma_mm),
                    ("--max-rotation-sigma-deg", max_rotation_sigma_deg)):
        if not v > 0:
            raise InputError(f"{name} {v}: must be positive")
    check_writable(out, sidecar_path(out))
    result = load_result(calibration)
    session = load_session(spec)
    for note in session.notes:
        if progress is not None:
            progress(note)
    noise = load_noise(noise_file, result.noise) if noise_file is not None else result.noise
    cal = calibration_for_groundtruth(result, Path(calibration), session.imu.time_origin_ns)
    if progress is not None:
        progress("smoothing the IMU between the mocap poses (Kalman filter + RTS smoother)")
    opts = GroundTruthOptions(rate_hz=rate_hz, max_position_sigma=max_position_sigma_mm * 1e-3,
                              max_rotation_sigma_deg=max_rotation_sigma_deg)
    gt = ground_truth(session.imu, session.mocap, cal, noise, opts)
    if len(gt.t_ns) == 0:
        raise InputError("no IMU state is trustworthy under the sigma limits (the mocap has too "
                         "many gaps, or the calibration is not this session's); raise "
                         "--max-position-sigma-mm / --max-rotation-sigma-deg or check the inputs")
    provenance = {"calibration": str(calibration), "inputs": list(session.notes),
                  "rate_hz": rate_hz if rate_hz is not None else "IMU stamps",
                  "noise": noise.to_dict()}
    path, side = write_groundtruth(out, gt, fmt, provenance)
    return GroundTruthRun(path, side, gt, list(session.notes))
