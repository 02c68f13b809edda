"""Compare a calibration with a reference (simulator truth, published values).

Errors are given in the same tangent spaces as the sigmas (``docs/conventions.md``), so
``error / sigma`` tells whether the reported uncertainty is honest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap_calib.core.model.parameters import (
    ACCEL_BIAS,
    GRAVITY_DIRECTION,
    GYRO_BIAS,
    ROTATION,
    TIME_OFFSET,
    TRANSLATION,
)
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


#: The rows' order: the rig's geometry, the biases, the world, the clock.
ORDER = (ROTATION, TRANSLATION, GYRO_BIAS, ACCEL_BIAS, GRAVITY_DIRECTION, TIME_OFFSET)


def _z(err: np.ndarray, sig: np.ndarray | None) -> float | None:
    if sig is None:
        return None
    return float(np.max(np.abs(err) / np.maximum(sig, 1e-300)))


def compare(result: CalibrationResult, ref: CalibrationResult) -> list[Row]:
    """Rows for every parameter both results have."""
    rows: list[Row] = []
    for p in ORDER:
        est, r = result.value(p), ref.value(p)
        if est is None or r is None:
            continue
        pr, sig = p.printed, result.sigma(p)
        if p.form == "so3":
            d = p.difference(p.state(r), p.state(est))
            rows.append(Row(pr.label, "deg", _vec(est), _vec(r),
                            float(np.degrees(np.linalg.norm(d))), _z(d, sig)))
        elif p.form == "s2":
            d = p.difference(est, r)
            ang = np.degrees(np.arccos(np.clip(np.dot(est, r), -1, 1)))
            rows.append(Row(pr.label, "deg", _vec(est), _vec(r), float(ang), _z(d, sig)))
        elif p.scalar:
            d = np.asarray(est) - np.asarray(r)
            k = pr.value_scale
            rows.append(Row(pr.label, pr.value_unit, f"{est[0] * k:.5g}", f"{r[0] * k:.5g}",
                            float(abs(d[0]) * k), _z(d, sig)))
        else:
            d = np.asarray(est) - np.asarray(r)
            k = pr.value_scale
            rows.append(Row(pr.label, pr.value_unit, _vec(est, k), _vec(r, k),
                            float(np.linalg.norm(d) * k), _z(d, sig)))
    return rows


def format_rows(rows: list[Row]) -> str:
    head = ("parameter", "estimate", "reference", "error", "unit", "|err|/sigma")
    body = [(r.name, r.estimate, r.reference, f"{r.error:.3g}", r.unit,
             "-" if r.z is None else f"{r.z:.2f}") for r in rows]
    return table(head, body)
