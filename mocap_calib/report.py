"""Readable text summaries of a calibration result (terminal, recordings, reports)."""

from __future__ import annotations

import numpy as np

from mocap_calib.core import so3
from mocap_calib.core.result import CalibrationResult


def _fmt(v: object, scale: float = 1.0, digits: int = 4) -> str:
    if v is None:
        return "unobservable"
    a = np.atleast_1d(np.asarray(v, dtype=float)).ravel() * scale
    if a.size == 1:
        return f"{a[0]:.{digits}g}"
    return "[" + ", ".join(f"{x:.{digits}g}" for x in a) + "]"


def summary_table(r: CalibrationResult) -> str:
    """Parameter | estimate | 1-sigma | unit, then the per-stage figures."""
    rows: list[tuple[str, str, str, str]] = []
    rpy = None
    if r.rotation_wxyz is not None:
        rpy = np.degrees(so3.log(so3.quat_to_rotmat(r.rotation_wxyz)))
    rows.append(("gyro_bias", _fmt(r.gyro_bias), _fmt(r.sigma_gyro_bias, digits=2), "rad/s"))
    rows.append(("accel_bias", _fmt(r.accel_bias), _fmt(r.sigma_accel_bias, digits=2), "m/s^2"))
    rows.append(("R_MI (rotation vector)", _fmt(rpy), _fmt(r.sigma_rotation, np.degrees(1.0), 2),
                 "deg"))
    rows.append(("R_MI (quaternion wxyz)", _fmt(r.rotation_wxyz, digits=6), "", ""))
    rows.append(("p_MI", _fmt(r.translation, 1e3), _fmt(r.sigma_translation, 1e3, 2), "mm"))
    rows.append(("gravity_in_mocap", _fmt(r.gravity_in_mocap, digits=6),
                 _fmt(r.sigma_gravity, np.degrees(1.0), 2), "- (sigma deg)"))
    if r.gravity_in_mocap is not None:
        tilt = np.degrees(np.arccos(np.clip(-r.gravity_in_mocap[2], -1, 1)))
        rows.append(("mocap z tilt from vertical", f"{tilt:.4g}", "", "deg"))
    sto = None if r.sigma_time_offset is None else r.sigma_time_offset * 1e3
    rows.append(("time_offset", _fmt(None if r.time_offset is None else r.time_offset * 1e3),
                 "fixed" if sto is None and r.time_offset is not None else _fmt(sto, digits=2),
                 "ms"))
    for name, rec in r.effects.items():
        for key, val in rec.items():
            if key == "sigma":
                continue
            rows.append((f"{name}.{key}", _fmt(val), _fmt(rec.get("sigma"), digits=2), ""))
    w = [max(len(row[i]) for row in rows + [("parameter", "estimate", "1-sigma", "unit")])
         for i in range(4)]
    lines = [f"{'parameter':<{w[0]}}  {'estimate':<{w[1]}}  {'1-sigma':<{w[2]}}  unit",
             "-" * (sum(w) + 8)]
    lines += [f"{a:<{w[0]}}  {b:<{w[1]}}  {c:<{w[2]}}  {d}" for a, b, c, d in rows]
    lines.append("")
    lines.append(f"{'stage':<9} {'factors':>8} {'residual RMS per axis (after)':<34} "
                 f"{'outliers':>8} {'iter':>5} {'chi2/dof':>9} {'time':>7}")
    for s in r.stages:
        unit = s.unit
        rms = s.rms_after
        if unit == "m":
            rms_txt = "[" + ", ".join(f"{x * 1e3:.3g}" for x in rms) + "] mm"
        elif unit == "deg":
            rms_txt = "[" + ", ".join(f"{x:.3g}" for x in rms) + "] deg"
        else:
            rms_txt = "[" + ", ".join(f"{x:.3g}" for x in rms) + f"] {unit}"
        lines.append(f"{s.name:<9} {s.n_factors:>8} {rms_txt:<34} {s.outliers:>8} "
                     f"{s.iterations:>5} {s.chi2_per_dof:>9.3f} {s.seconds:>6.1f}s")
    if r.unobservable:
        lines.append("")
        for k, why in r.unobservable.items():
            lines.append(f"UNOBSERVABLE {k}: {why}")
    for n in r.notes:
        lines.append(f"note: {n}")
    return "\n".join(lines)
