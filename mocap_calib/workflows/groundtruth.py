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
from mocap_calib.core.model.effects import EFFECTS
from mocap_calib.core.params import group, param
from mocap_calib.core.pipeline.calibrate import ProgressFn
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.errors import InputError
from mocap_calib.export.intrinsics import intrinsics_of
from mocap_calib.io.groundtruth import GT_FORMATS, sidecar_path, write_sidecar, write_trajectory
from mocap_calib.io.yaml_io import load_result, non_finite
from mocap_calib.workflows.outputs import Named, OutputPlan, Product, output, write_products
from mocap_calib.workflows.session import InputSpec, NoiseSpec, load_session

__all__ = ["GT_FORMATS", "GroundTruthRun", "GroundtruthRequest", "run_groundtruth"]

#: ``--rate``'s bound before the IMU's rate is known (``simulate``'s highest IMU rate) and how
#: far above the IMU's measured rate a requested one may be (its stamps jitter).
MAX_RATE_HZ = 1e5
RATE_SLACK = 0.01


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
    # Bias trends: the effects whose term is linear in time, by the sensor they act on.
    rate = {"gyro": np.zeros(3), "accel": np.zeros(3)}
    for eff in EFFECTS.values():
        value = (result.effects.get(eff.name) or {}).get(eff.param)
        if eff.acts_on == "time" and value is not None:
            rate[eff.sensor] = np.asarray(value, dtype=float)
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
        accel_matrix=intr.accel_matrix, t_mid_s=t_mid,
        gyro_bias_rate=rate["gyro"], accel_bias_rate=rate["accel"],
        sigma_gyro_bias=(np.full(3, 1e-3) if result.sigma_gyro_bias is None
                         else np.asarray(result.sigma_gyro_bias)),
        sigma_accel_bias=(np.full(3, 2e-2) if result.sigma_accel_bias is None
                          else np.asarray(result.sigma_accel_bias)))


@dataclass
class GroundtruthRequest:
    """Everything ``groundtruth`` can be told: the inputs as ``calibrate``'s, the calibration,
    the noise model (default: the calibration's), the output and its limits."""

    inputs: InputSpec = group(InputSpec, "Input")
    noise: NoiseSpec = group(NoiseSpec, "Noise model")
    calibration: Path = param(Path("calib.yaml"), "result YAML of 'mocap-calib calibrate' for "
                              "this rig (and clock)", metavar="PATH")
    out: Path = output(Path("gt.csv"), "trajectory file to write (and beside it its YAML "
                       "sidecar: gt.csv -> gt.yaml)", metavar="PATH")
    format: str = param("euroc", "euroc (state_groundtruth_estimate0 layout) or tum",
                        choices=GT_FORMATS)
    rate: float | None = param(None, "output rate on the IMU clock, at most the IMU's own "
                               "(default: at the IMU stamps)", unit="Hz", lo=0.0, lo_open=True,
                               hi=MAX_RATE_HZ, show_default=False)
    max_position_sigma_mm: float = param(
        2.0, "leave out states whose smoothed position 1-sigma exceeds this", unit="mm",
        lo=0.0, lo_open=True)
    max_rotation_sigma_deg: float = param(
        0.1, "leave out states whose smoothed attitude 1-sigma exceeds this", unit="deg",
        lo=0.0, lo_open=True, hi=180.0)
    quiet: bool = param(False, "no progress lines", decls=("--quiet", "-q"))

    def plan(self) -> OutputPlan:
        return OutputPlan.of(self, outputs=[Named("--out", sidecar_path(self.out), "its sidecar")])


def _check_rate(rate: float | None, imu_rate_hz: float) -> None:
    """A rate above the IMU's only interpolates between its states (and memory grows with
    it: 100 kHz over a minute is gigabytes)."""
    if rate is not None and rate > imu_rate_hz * (1.0 + RATE_SLACK):
        raise InputError(f"--rate {rate:g} Hz: above the IMU's own {imu_rate_hz:.6g} Hz; states "
                         "between IMU samples only interpolate them: give at most "
                         f"{imu_rate_hz:.6g}, or leave --rate out for the IMU stamps")


def _check_calibration(result: CalibrationResult, source: Path) -> None:
    bad = non_finite(result.to_dict())
    if bad:
        raise InputError(f"{source}: {bad}, not a number a calibration can have; the ground "
                         "truth needs a calibration of finite numbers: calibrate again")


def run_groundtruth(request: GroundtruthRequest,
                    progress: ProgressFn | None = None) -> GroundTruthRun:
    """Read the session and the calibration, smooth, write the trajectory and its sidecar."""
    out, calibration = request.out, request.calibration
    request.plan().check()
    result = load_result(calibration)
    _check_calibration(result, Path(calibration))
    session = load_session(request.inputs, result.time_offset)
    _check_rate(request.rate, session.imu.rate_hz)
    for note in session.notes:
        if progress is not None:
            progress(note)
    noise = request.noise.resolve(result.noise, f"{calibration} (its noise model)")
    cal = calibration_for_groundtruth(result, Path(calibration), session.imu.time_origin_ns)
    if progress is not None:
        progress("smoothing the IMU between the mocap poses (Kalman filter + RTS smoother)")
    opts = GroundTruthOptions(rate_hz=request.rate,
                              max_position_sigma=request.max_position_sigma_mm * 1e-3,
                              max_rotation_sigma_deg=request.max_rotation_sigma_deg)
    gt = ground_truth(session.imu, session.mocap, cal, noise, opts)
    if len(gt.t_ns) == 0:
        raise InputError("no IMU state is trustworthy under the sigma limits (the mocap has too "
                         "many gaps, or the calibration is not this session's); raise "
                         "--max-position-sigma-mm / --max-rotation-sigma-deg or check the inputs")
    provenance = {"calibration": str(calibration), "inputs": list(session.notes),
                  "rate_hz": request.rate if request.rate is not None else "IMU stamps",
                  "noise": noise.to_dict()}
    side = sidecar_path(out)
    write_products([
        Product("--out", out, lambda: write_trajectory(out, gt, request.format)),
        Product("--out", side, lambda: write_sidecar(out, gt, request.format,
                                                                provenance)),
    ])
    return GroundTruthRun(Path(out), side, gt, list(session.notes))
