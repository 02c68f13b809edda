"""Compare a calibration with a reference (simulator truth, published values).

Errors are given in the same tangent spaces as the sigmas (``docs/conventions.md``), so
``error / sigma`` tells whether the reported uncertainty is honest.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from mocap_calib.core.model import so3
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.report.text import table


@dataclass
class Row:
    """One parameter: estimate, reference, error (norm, in ``unit``) and max |error| / sigma."""

    name: str
    unit: str
    estimate: str
    reference: str
    error: float
    z: float | None


def _vec(x: object, scale: float = 1.0) -> str:
    a = np.atleast_1d(np.asarray(x, dtype=float)) * scale
    return "[" + ", ".join(f"{v:.5g}" for v in a) + "]"


def compare(result: CalibrationResult, ref: CalibrationResult) -> list[Row]:
    """Rows for every parameter both results have."""
    rows: list[Row] = []

    def z(err: np.ndarray, sig: np.ndarray | None) -> float | None:
        if sig is None:
            return None
        return float(np.max(np.abs(err) / np.maximum(sig, 1e-300)))

    if result.rotation_wxyz is not None and ref.rotation_wxyz is not None:
        R_ref = so3.quat_to_rotmat(ref.rotation_wxyz)
        d = so3.log(R_ref.T @ so3.quat_to_rotmat(result.rotation_wxyz))
        rows.append(Row("R_MI", "deg", _vec(result.rotation_wxyz), _vec(ref.rotation_wxyz),
                        float(np.degrees(np.linalg.norm(d))), z(d, result.sigma_rotation)))
    pairs = (("p_MI", "mm", result.translation, ref.translation, result.sigma_translation, 1e3),
             ("gyro_bias", "rad/s", result.gyro_bias, ref.gyro_bias, result.sigma_gyro_bias, 1.0),
             ("accel_bias", "m/s^2", result.accel_bias, ref.accel_bias, result.sigma_accel_bias,
              1.0))
    for name, unit, est, r, sig, scale in pairs:
        if est is None or r is None:
            continue
        d = np.asarray(est) - np.asarray(r)
        rows.append(Row(name, unit, _vec(est, scale), _vec(r, scale),
                        float(np.linalg.norm(d) * scale), z(d, sig)))
    if result.gravity_in_mocap is not None and ref.gravity_in_mocap is not None:
        u = gtsam.Unit3(np.asarray(result.gravity_in_mocap))
        d = np.asarray(u.localCoordinates(gtsam.Unit3(np.asarray(ref.gravity_in_mocap))))
        ang = np.degrees(np.arccos(np.clip(np.dot(result.gravity_in_mocap, ref.gravity_in_mocap),
                                           -1, 1)))
        rows.append(Row("gravity_in_mocap", "deg", _vec(result.gravity_in_mocap),
                        _vec(ref.gravity_in_mocap), float(ang), z(d, result.sigma_gravity)))
    if result.time_offset is not None and ref.time_offset is not None:
        d = np.array([result.time_offset - ref.time_offset])
        sig = None if result.sigma_time_offset is None else np.array([result.sigma_time_offset])
        rows.append(Row("time_offset", "ms", f"{result.time_offset * 1e3:.5g}",
                        f"{ref.time_offset * 1e3:.5g}", float(abs(d[0]) * 1e3), z(d, sig)))
    return rows


def format_rows(rows: list[Row]) -> str:
    head = ("parameter", "estimate", "reference", "error", "unit", "|err|/sigma")
    body = [(r.name, r.estimate, r.reference, f"{r.error:.3g}", r.unit,
             "-" if r.z is None else f"{r.z:.2f}") for r in rows]
    return table(head, body)
