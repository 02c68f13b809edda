"""Text summaries of the mocap-free tools: multipos intrinsics, Allan noise model, drift check."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mocap_calib.core.intrinsics.attitude_drift import AttitudeDriftResult
from mocap_calib.core.intrinsics.multipos.result import MultiposResult
from mocap_calib.core.intrinsics.noise_result import AllanResult, SensorNoise
from mocap_calib.report.text import table

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


def _raw_rows(r: MultiposResult, sensor: str) -> list[tuple[str, str, str, str]]:
    """Raw counts: imu_tk's scale ``K`` per axis (SI per count) and offset ``b`` (counts)."""
    assert r.raw_input is not None
    tk = r.imu_tk()[sensor]
    M = getattr(r, f"{sensor}_matrix")
    S = getattr(r, f"{sensor}_matrix_sigma")
    rel = np.diag(S) / np.abs(np.diag(M))
    unit = "m/s^2/count" if sensor == "accel" else "rad/s/count"
    rows = [(f"{sensor} scale K {'xyz'[i]}", f"{tk['K'][i, i]:.6e}",
             f"{rel[i] * tk['K'][i, i]:.2g}", unit) for i in range(3)]
    bsig = getattr(r, f"{sensor}_bias_sigma") / r.raw_input.scale(sensor)
    rows += [(f"{sensor} offset b {'xyz'[i]}", f"{tk['b'][i]:+.3f}", f"{bsig[i]:.2g}", "counts")
             for i in range(3)]
    return rows


def _g_rows(r: MultiposResult) -> list[tuple[str, str, str, str]]:
    if r.g_sensitivity is None or r.g_sensitivity_sigma is None:
        return []
    G, S = r.g_sensitivity, r.g_sensitivity_sigma
    return [(f"gyro g-sensitivity {'xyz'[i]}{'xyz'[j]}", f"{G[i, j]:+.3e}", f"{S[i, j]:.2g}",
             "rad/s/(m/s^2)") for i in range(3) for j in range(3)]


def _detector_lines(r: MultiposResult) -> list[str]:
    scan = ", ".join(f"{e['k']:g}: {e['n_intervals']}" for e in r.threshold_scan)
    return [f"static detector     threshold multiple k = {r.threshold_multiple:g}, "
            f"{r.n_static_intervals} static intervals, "
            f"{r.n_distinct_orientations} distinct orientations",
            f"                    (static where |var_w(a)| < k |var_init(a)|, imu_tk's "
            f"meaning; intervals found per k: {scan})"]


def _g_line(r: MultiposResult) -> list[str]:
    t = r.g_sensitivity_test
    if not t:
        return []
    verdict = "kept" if t["kept"] else "left out"
    return [f"g-sensitivity G     {verdict} (likelihood ratio T = {t['statistic']:.3g}, "
            f"log10 p = {t['log10_p']:.3g}, {'' if t['significant'] else 'not '}significant); "
            f"gyro residual {np.degrees(t['gyro_rms_rad_with_g']):.3g} deg with G, "
            f"{np.degrees(t['gyro_rms_rad_without_g']):.3g} deg without"]


def multipos_summary(r: MultiposResult) -> str:
    """Table of the intrinsics (scale errors in %, misalignments in deg; for raw counts imu_tk's
    scales and offsets), the fit figures, the g-sensitivity test and the poorly determined
    parameters."""
    raw = r.raw_input is not None
    # Scale errors mean something only against a nominal scale: SI input or a given one.
    errors = not raw or (r.raw_input is not None and r.raw_input.source == "given")
    rows: list[tuple[str, str, str, str]] = []
    for sensor, M, S, lower in (("accel", r.accel_matrix, r.accel_matrix_sigma, True),
                                ("gyro", r.gyro_matrix, r.gyro_matrix_sigma, False)):
        if raw:
            rows += _raw_rows(r, sensor)
        rows += [row for row in _matrix_rows(sensor, M, S, lower)
                 if errors or "scale error" not in row[0]]
        bias = getattr(r, f"{sensor}_bias")
        bsig = getattr(r, f"{sensor}_bias_sigma")
        unit = "m/s^2" if sensor == "accel" else "rad/s"
        for i in range(3):
            rows.append((f"{sensor} bias {'xyz'[i]}", f"{bias[i]:+.6f}", f"{bsig[i]:.2g}", unit))
    rows += _g_rows(r)
    lines = [table(("parameter", "estimate", "1-sigma", "unit"), rows,
                        (False, True, True, False)), ""]
    lines.append(f"accel residual RMS  {1e3 * r.accel_residual_rms:.3g} mm/s^2 "
                 f"(|h| - g over the static intervals; chi2/dof {r.accel_chi2:.3g})")
    lines.append(f"gyro residual RMS   {np.degrees(r.gyro_residual_rms):.3g} deg "
                 f"(gravity direction after each rotation; chi2/dof {r.gyro_chi2:.3g})")
    lines += _detector_lines(r) + _g_line(r)
    if r.raw_input is not None:
        what = "the nominal scales given" if r.raw_input.source == "given" else "imu_tk's K"
        lines.append(f"raw counts          SI values for x = scale (raw - offset) with "
                     f"{what} ('raw_input'); imu_tk's T K (raw - b) under 'imu_tk'")
    if r.prior_source is not None:
        lines.append(f"prior               {r.prior_source}")
    g = "" if r.g_sensitivity is None else " + G f"
    lines.append(f"model               a_m = M_a f + b_a, w_m = M_g w{g} + b_g "
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
    lines = [table(("sensor", "axis", "noise density N", "random walk K",
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
             table(("at the segment end", "raw gyro (deg)", "calibrated (deg)"), rows,
                        (False, True, True)), "",
             f"reduction of the tilt drift: {100 * r.reduction:.1f} %"]
    if len(r.series_t):
        lines.append(f"along the mocap reference: max tilt drift raw "
                     f"{np.max(r.series_tilt_raw_deg):.4f} deg, calibrated "
                     f"{np.max(r.series_tilt_cal_deg):.4f} deg")
    lines += [f"note: {n}" for n in notes]
    return "\n".join(lines)
