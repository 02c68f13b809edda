"""The HTML reports of ``multipos`` and ``allan``: the per-pose residuals of a multi-position
calibration (computed here from the result and the log), and the pages."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mocap_calib.core.intrinsics.multipos import MultiposResult
from mocap_calib.core.intrinsics.noise_result import AllanResult
from mocap_calib.core.model import so3
from mocap_calib.core.model.preint import quat_increments, quat_product, sample_nodes
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.report.html.intrinsics import PoseResiduals
from mocap_calib.workflows.report_files.pages import write_report
from mocap_calib.workflows.report_files.provenance import RunClock


def pose_residuals(result: MultiposResult, imu: ImuSamples) -> PoseResiduals:
    """Residuals of the calibrated model per static pose and per rotation.

    Accelerometer: ``|h_i| - g`` with ``h_i = M_a^-1 (mean_i - b_a)`` the calibrated specific
    force of static interval ``i``. Gyroscope: the distance between the gravity direction of
    the next pose and that of the previous pose carried through the calibrated rotation
    ``w = M_g^-1 (w_m - b_g - G f)`` integrated over the samples between them (the quantity
    the gyroscope fit minimises; its RMS is the result's ``gyro_rms_rad``).
    """
    x = imu if result.raw_input is None else result.raw_input.apply(imu)
    iv = np.searchsorted(imu.t, result.static_intervals)
    M_a_inv = np.linalg.inv(result.accel_matrix)
    means = np.stack([x.accel[a:b + 1].mean(axis=0) for a, b in iv])
    h = (means - result.accel_bias) @ M_a_inv.T
    norm = np.linalg.norm(h, axis=1)
    u = h / norm[:, None]
    M_g_inv = np.linalg.inv(result.gyro_matrix)
    errs = []
    for k in range(len(iv) - 1):
        idx = np.arange(iv[k, 1], iv[k + 1, 0] + 1)
        offset = np.broadcast_to(result.gyro_bias, (len(idx), 3))
        if result.g_sensitivity is not None:
            f = (x.accel[idx] - result.accel_bias) @ M_a_inv.T
            offset = offset + f @ result.g_sensitivity.T
        w = (x.gyro[idx] - offset) @ M_g_inv.T
        q = quat_product(quat_increments(sample_nodes(w[None]), np.diff(imu.t[idx])[None]))
        R = so3.quat_to_rotmat(q)[0]
        errs.append(float(np.linalg.norm(R.T @ u[k] - u[k + 1])))
    mid = 0.5 * (result.static_intervals[:, 0] + result.static_intervals[:, 1])
    rot_t = 0.5 * (result.static_intervals[:-1, 1] + result.static_intervals[1:, 0])
    return PoseResiduals(mid - imu.t[0], norm - result.gravity, rot_t - imu.t[0],
                         np.asarray(errs))


def write_multipos_html(path: Path, result: MultiposResult, imu: ImuSamples,
                        inputs: Sequence[Path | None], clock: RunClock) -> Path:
    """The ``multipos --html`` page."""
    from mocap_calib.report.html import multipos_sections

    sections = multipos_sections(result, imu, pose_residuals(result, imu))
    poor = result.poorly_determined
    verdict = (("all parameters determined", "ok") if not poor
               else (f"poorly determined: {', '.join(poor)}", "warn"))
    sub = (f"{result.n_static_intervals} static intervals, {result.n_distinct_orientations} "
           f"distinct orientations, threshold multiple k = {result.threshold_multiple:g}")
    return write_report(path, "mocap-calib multi-position intrinsics report", sections, inputs,
                        clock, sub, verdict)


def write_allan_html(path: Path, result: AllanResult, inputs: Sequence[Path | None],
                     clock: RunClock) -> Path:
    """The ``allan --html`` page."""
    from mocap_calib.report.html import allan_sections

    unresolved = [s.sensor for s in (result.gyroscope, result.accelerometer)
                  if not np.all(s.random_walk_resolved)]
    verdict = (("random walks resolved", "ok") if not unresolved
               else (f"random walk not resolved: {', '.join(unresolved)}", "warn"))
    sub = (f"{result.duration_s / 3600:.2f} h static log at {result.rate_hz:.4g} Hz "
           f"({result.n_samples} samples); Kalibr keys: {result.aggregate} over the axes")
    return write_report(path, "mocap-calib Allan deviation noise report", allan_sections(result),
                        inputs, clock, sub, verdict)
