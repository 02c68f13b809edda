"""The signature of a residual no candidate explains: where a person should look.

When the diagnosis stops with the residual still above the noise floor, naming a wrong effect
would mislead; instead the report describes the gap:

- which sensor and axes carry it (low-band residual over the floor, per axis);
- in which frequency band (residual over floor power, Welch);
- how it correlates with the angular rate, the angular acceleration and the specific force
  (the strongest linear correlation between a residual axis and a signal axis, and between
  the magnitudes): a rate-proportional residual points at scale or lag, an acceleration-
  proportional one at a lever arm or a mount that is not rigid;
- where in time it sits: its RMS per time segment, and the clock offset fitted per segment (a
  jump or a steady drift there points at the clocks, not at the IMU).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.diagnosis.predict import ResidualAnalysis, lowpass, predict_imu
from mocap_calib.core.diagnosis.report import Residuals
from mocap_calib.core.model.parameters import TIME_OFFSET
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position.stage import PositionResult
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.core.result.state import ModelState
from mocap_calib.core.uncertainty.segments import segment_consistency

Array = NDArray[np.float64]

AXES = "xyz"


def unexplained_signature(s: PreparedSession, st: ModelState, ra: ResidualAnalysis,
                          pos: PositionResult, ratio_limit: float,
                          segments: int = 6) -> dict[str, Any]:
    """Describe the residual left (see the module docstring); ``ratio_limit``: the per-axis
    residual/floor ratio above which an axis counts as carrying the gap."""
    pred = predict_imu(s, st)
    rate = s.imu_rate
    keep = ra.keep
    out: dict[str, Any] = {}
    for sensor, rms, floor, lp in (("gyro", ra.gyro_rms, ra.gyro_floor, ra.gyro_lp),
                                   ("accel", ra.accel_rms, ra.accel_floor, ra.accel_lp)):
        ratio = rms / np.maximum(floor, 1e-300)
        bands = ra.band_ratios()[sensor]
        worst_band = max(bands, key=lambda b: max(bands[b])) if bands else None
        out[sensor] = {
            "ratio_per_axis": [round(float(x), 3) for x in ratio],
            "axes_over_floor": [AXES[i] for i in np.flatnonzero(ratio > ratio_limit)],
            "band_most_over_floor": worst_band,
            "correlation": _correlations(lp, pred, rate, ra.cutoff_hz, keep),
            "rms_per_time_segment": _per_segment(lp, keep, segments),
        }
    out["clock_offset_per_segment"] = _clock_profile(s, st, pos, segments)
    return out


def _correlations(lp: Array, pred, rate: float, cutoff: float,
                  keep: NDArray[np.bool_]) -> dict[str, Any]:
    """Strongest correlation of the low-passed residual with each signal, by axis and by
    magnitude."""
    w = pred.w
    alpha = np.concatenate([np.gradient(w[seg], pred.u[seg], axis=0) if len(seg) > 2
                            else np.zeros((len(seg), 3)) for seg in pred.segments])
    out = {}
    for name, sig in (("angular_rate", w), ("angular_acceleration", alpha),
                      ("specific_force", pred.f)):
        x = lowpass(sig, rate, cutoff, pred.segments)[keep]
        r = lp[keep]
        c = np.array([[_corr(r[:, i], x[:, j]) for j in range(3)] for i in range(3)])
        i, j = np.unravel_index(int(np.argmax(np.abs(c))), c.shape)
        out[name] = {"max_abs_corr": round(float(c[i, j]), 3),
                     "residual_axis": AXES[i], "signal_axis": AXES[j],
                     "magnitude_corr": round(_corr(np.linalg.norm(r, axis=1),
                                                   np.linalg.norm(x, axis=1)), 3)}
    return out


def _corr(a: Array, b: Array) -> float:
    sa, sb = float(np.std(a)), float(np.std(b))
    if sa == 0.0 or sb == 0.0:
        return 0.0
    return float(np.mean((a - a.mean()) * (b - b.mean())) / (sa * sb))


def _per_segment(lp: Array, keep: NDArray[np.bool_], k: int) -> list[float]:
    """Residual RMS in ``k`` consecutive parts of the session (over its overall RMS)."""
    idx = np.flatnonzero(keep)
    total = float(np.sqrt(np.mean(lp[idx] ** 2))) or 1.0
    return [round(float(np.sqrt(np.mean(lp[p] ** 2))) / total, 3)
            for p in np.array_split(idx, k) if len(p)]


def _clock_profile(s: PreparedSession, st: ModelState, pos: PositionResult,
                   k: int) -> dict[str, Any]:
    """The clock offset fitted per time segment (needs the offset in the model), with the
    slope of a straight line through them (ppm) and the largest jump between neighbours."""
    if TIME_OFFSET.name not in pos.cov:
        return {"note": "time_offset is not in the model"}
    cons = segment_consistency(pos, st.model, k)
    if not cons.segments:
        return {"note": cons.note}
    t = np.array([0.5 * (g.start_s + g.end_s) for g in cons.segments])
    td = np.array([g.est.t_d for g in cons.segments])
    sig = np.array([g.est.sigma[TIME_OFFSET][0] for g in cons.segments])
    slope = float(np.polyfit(t, td, 1, w=1.0 / sig)[0]) if len(t) > 2 else 0.0
    jumps = np.abs(np.diff(td)) / np.hypot(sig[1:], sig[:-1])
    return {"t_s": [round(float(x), 2) for x in t],
            "t_d_ms": [round(1e3 * float(x), 4) for x in td],
            "sigma_ms": [round(1e3 * float(x), 4) for x in sig], "slope_ppm": round(1e6 * slope, 2),
            "largest_jump_sigmas": round(float(jumps.max()), 2) if len(jumps) else 0.0}


def why_unexplained(res: Residuals, noise: NoiseModel, ratio: float,
                    typical_mocap_noise: tuple[float, float]) -> list[str]:
    """Why the data hold more than the model and the noise: the residual above the floor, or a
    mocap noise no mocap system has (a slow model error taken for noise)."""
    why = []
    for sensor in ("gyro", "accel"):
        if res.ratio(sensor) > ratio:
            why.append(f"the {sensor} residual is {res.ratio(sensor):.2f} x the noise floor")
    pos, rot = typical_mocap_noise
    if noise.mocap_position_sigma > pos or noise.mocap_rotation_sigma > rot:
        corr = (f", correlated over {noise.mocap_noise_corr_time:g} s"
                if noise.mocap_correlated else "")
        why.append(f"the residuals imply mocap noise of {1e3 * noise.mocap_position_sigma:.2g} mm "
                   f"and {np.degrees(noise.mocap_rotation_sigma):.2g} deg per sample{corr}, "
                   f"beyond a mocap system's ({1e3 * pos:g} mm, {np.degrees(rot):g} deg): "
                   "a slow error the model does not describe")
    return why
