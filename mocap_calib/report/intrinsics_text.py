"""Text summaries of the mocap-free tools: multipos intrinsics, Allan noise model, drift check."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mocap_calib.core.intrinsics.attitude_drift import AttitudeDriftResult
from mocap_calib.core.intrinsics.multipos.result import MultiposResult
from mocap_calib.core.intrinsics.noise_result import AllanResult, SensorNoise


def text_table(header: Sequence[str], rows: Sequence[Sequence[str]],
               right: Sequence[bool]) -> str:
    """Columns padded to their widest cell; ``right`` aligns numeric columns right."""
    w = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]

    def line(r: Sequence[str]) -> str:
        return "  ".join(f"{c:>{w[i]}}" if right[i] else f"{c:<{w[i]}}"
                         for i, c in enumerate(r)).rstrip()

    return "\n".join([line(header), "-" * (sum(w) + 2 * (len(w) - 1)), *map(line, rows)])


# --------------------------------------------------------------------------------------------
# multipos
# --------------------------------------------------------------------------------------------

def _matrix_rows(sensor: str, M: np.ndarray, S: np.ndarray, lower: bool
                 ) -> list[tuple[str, str, str, str]]:
    """Scale errors (%) and misalignments (deg) of ``M = diag(s) (I + E)``."""
    rows = []
    d = np.diag(M)
    for i in range(3):
        rows.append((f"{sensor} scale error {'xyz'[i]}", f"{100 * (d[i] - 1):+.4f}",
                     f"{100 * S[i, i]:.4f}", "%"))
    # M = diag(s) (I + E): the misalignment angle of entry (i, j) is E_ij = M_ij / s_i.
    for i in range(3):
        for j in range(3):
            if i == j or (lower and j > i):
                continue
            rows.append((f"{sensor} misalignment {'xyz'[i]}{'xyz'[j]}",
                         f"{np.degrees(M[i, j] / d[i]):+.4f}",
                         f"{np.degrees(S[i, j] / d[i]):.4f}", "deg"))
    return rows


def multipos_summary(r: MultiposResult) -> str:
    """Table of the intrinsics (scale errors in %, misalignments in deg), the fit figures and
    the poorly determined parameters."""
    rows: list[tuple[str, str, str, str]] = []
    for sensor, M, S, lower in (("accel", r.accel_matrix, r.accel_matrix_sigma, True),
                                ("gyro", r.gyro_matrix, r.gyro_matrix_sigma, False)):
        rows += _matrix_rows(sensor, M, S, lower)
        bias = getattr(r, f"{sensor}_bias")
        bsig = getattr(r, f"{sensor}_bias_sigma")
        unit = "m/s^2" if sensor == "accel" else "rad/s"
        for i in range(3):
            rows.append((f"{sensor} bias {'xyz'[i]}", f"{bias[i]:+.6f}", f"{bsig[i]:.2g}", unit))
    lines = [text_table(("parameter", "estimate", "1-sigma", "unit"), rows,
                        (False, True, True, False)), ""]
    lines.append(f"accel residual RMS  {1e3 * r.accel_residual_rms:.3g} mm/s^2 "
                 f"(|h| - g over the static intervals; chi2/dof {r.accel_chi2:.3g})")
    lines.append(f"gyro residual RMS   {np.degrees(r.gyro_residual_rms):.3g} deg "
                 f"(gravity direction after each rotation; chi2/dof {r.gyro_chi2:.3g})")
    lines.append(f"static detector     threshold multiple k = {r.threshold_multiple:g}, "
                 f"{r.n_static_intervals} static intervals, "
                 f"{r.n_distinct_orientations} distinct orientations")
    if r.prior_source is not None:
        lines.append(f"prior               {r.prior_source}")
    lines.append("model               a_m = M_a f + b_a, w_m = M_g w + b_g "
                 "(M = diag(1 + scale error) (I + misalignment))")
    if r.poorly_determined:
        lines.append("")
        lines += [f"POORLY DETERMINED {p}" for p in r.poorly_determined]
    else:
        lines.append("poorly determined   none")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# allan
# --------------------------------------------------------------------------------------------

_ALLAN_UNITS = {"gyroscope": ("rad/s/sqrt(Hz)", "rad/s^2/sqrt(Hz)", "rad/s"),
                "accelerometer": ("m/s^2/sqrt(Hz)", "m/s^3/sqrt(Hz)", "m/s^2")}


def _pm(v: float, s: float) -> str:
    if not np.isfinite(v):
        return "unresolved"
    return f"{v:.4g} +- {s:.2g}" if np.isfinite(s) else f"{v:.4g}"


def allan_summary(r: AllanResult) -> str:
    """Per-axis table of N, K, B (with 1-sigma) and the Kalibr values written."""
    rows: list[tuple[str, ...]] = []
    s: SensorNoise
    for s in (r.gyroscope, r.accelerometer):
        for ax in range(3):
            rows.append((s.sensor, "xyz"[ax],
                         _pm(s.noise_density[ax], s.noise_density_sigma[ax]),
                         _pm(s.random_walk[ax], s.random_walk_sigma[ax]),
                         f"{s.bias_instability[ax]:.4g}", f"{s.tau_at_minimum[ax]:.4g}",
                         f"{s.fit_chi2[ax]:.3g}"))
    lines = [text_table(("sensor", "axis", "noise density N", "random walk K",
                         "bias instab. B", "tau(min) s", "chi2"), rows,
                        (False, False, True, True, True, True, True)),
             "units: gyroscope N rad/s/sqrt(Hz), K rad/s^2/sqrt(Hz), B rad/s; "
             "accelerometer N m/s^2/sqrt(Hz), K m/s^3/sqrt(Hz), B m/s^2", ""]
    d = r.to_dict()
    lines.append(f"Kalibr imu.yaml ({r.aggregate} over the axes, {r.rate_hz:.4g} Hz, "
                 f"{r.duration_s / 3600:.2f} h log):")
    for sensor, (nu, ku, _) in _ALLAN_UNITS.items():
        for key, unit in ((f"{sensor}_noise_density", nu), (f"{sensor}_random_walk", ku)):
            v = d[key]
            lines.append(f"  {key + ':':<32} "
                         f"{'null (not resolved)' if v is None else f'{v:.6g}'}  {unit}")
    for k, why in d.get("unobservable", {}).items():
        lines.append(f"UNOBSERVABLE {k}: {why}")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# drift
# --------------------------------------------------------------------------------------------

def drift_summary(r: AttitudeDriftResult, calibration_file: str, calibration_kind: str,
                  notes: Sequence[str]) -> str:
    """Roll, pitch and tilt drift before/after and the reduction."""
    rows = [(what, f"{getattr(r, f'{key}_drift_raw_deg'):+.4f}",
             f"{getattr(r, f'{key}_drift_cal_deg'):+.4f}")
            for what, key in (("roll drift", "roll"), ("pitch drift", "pitch"),
                              ("tilt drift (angle)", "tilt"))]
    src = {"reference": "mocap", "accel": "accelerometer at rest"}
    lines = [f"segment {r.t0:.3f} - {r.t1:.3f} s after the IMU start ({r.duration:.1f} s); "
             f"initial attitude: {src.get(r.initial_source, r.initial_source)}, reference: "
             f"{src.get(r.reference_source, r.reference_source)}",
             f"calibration: {calibration_file} ({calibration_kind})", "",
             text_table(("at the segment end", "raw gyro (deg)", "calibrated (deg)"), rows,
                        (False, True, True)), "",
             f"reduction of the tilt drift: {100 * r.reduction:.1f} %"]
    if len(r.series_t):
        lines.append(f"along the mocap reference: max tilt drift raw "
                     f"{np.max(r.series_tilt_raw_deg):.4f} deg, calibrated "
                     f"{np.max(r.series_tilt_cal_deg):.4f} deg")
    lines += [f"note: {n}" for n in notes]
    return "\n".join(lines)
