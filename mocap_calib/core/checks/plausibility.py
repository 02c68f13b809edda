"""The plausibility gate: a calibration that no physical rig could have is refused.

Every answer is checked against :class:`~mocap_calib.core.plausible.PlausibleLimits`:
bias magnitudes, the lever arm, the mocap world's tilt against its nearest axis (the up axis is
reported: y-up OptiTrack worlds are as legitimate as z-up Vicon ones), the mocap noise the
residuals imply, how far the fine fit moved the clock from the coarse search, and each effect's
own range. An answer that fails is not printed as a success: the command exits 4 with the
reasons, unless the user accepts it explicitly, and then the result file says so.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mocap_calib.core.model.effects import EFFECTS
from mocap_calib.core.model.parameters import (
    ACCEL_BIAS,
    GRAVITY_DIRECTION,
    GYRO_BIAS,
    TRANSLATION,
)
from mocap_calib.core.plausible import PlausibleLimits, effect_problem, up_axis
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.result.verdicts import Plausibility, PlausibilityFigures


def check_plausibility(r: CalibrationResult, limits: PlausibleLimits,
                       coarse_time_offset: float | None = None) -> Plausibility:
    """The failed checks (one line each) and the figures checked."""
    failed: list[str] = []
    fig: dict[str, Any] = {}
    gyro_bias, accel_bias = r.value(GYRO_BIAS), r.value(ACCEL_BIAS)
    if gyro_bias is not None:
        v = float(np.abs(gyro_bias).max())
        fig["gyro_bias_max_rad_s"] = round(v, 5)
        if v > limits.gyro_bias:
            failed.append(f"gyro bias of {v:.3g} rad/s (plausible up to {limits.gyro_bias:g})")
    if accel_bias is not None:
        v = float(np.abs(accel_bias).max())
        fig["accel_bias_max_m_s2"] = round(v, 5)
        if v > limits.accel_bias:
            failed.append(f"accel bias of {v:.3g} m/s^2 (plausible up to {limits.accel_bias:g})")
    translation, g_dir = r.value(TRANSLATION), r.value(GRAVITY_DIRECTION)
    if translation is not None:
        v = float(np.linalg.norm(translation))
        fig["lever_arm_m"] = round(v, 5)
        if v > limits.lever_arm:
            failed.append(f"IMU {v:.3g} m from the marker body's origin (plausible up to "
                          f"{limits.lever_arm:g} m)")
    if g_dir is not None:
        axis, tilt = up_axis(g_dir)
        fig["up_axis"] = axis
        fig["tilt_deg"] = round(tilt, 4)
        if tilt > limits.tilt_deg:
            failed.append(f"mocap world tilted {tilt:.1f} deg from its nearest axis ({axis} up; "
                          f"plausible up to {limits.tilt_deg:g} deg)")
    sp, sr = r.noise.mocap_position_sigma, float(np.degrees(r.noise.mocap_rotation_sigma))
    fig["mocap_noise_mm_deg"] = (round(1e3 * sp, 4), round(sr, 4))
    if sp > limits.mocap_position_sigma_m or sr > limits.mocap_rotation_sigma_deg:
        failed.append(f"residuals imply mocap noise of {1e3 * sp:.3g} mm and {sr:.3g} deg per "
                      f"sample (plausible up to {1e3 * limits.mocap_position_sigma_m:g} mm, "
                      f"{limits.mocap_rotation_sigma_deg:g} deg): the model does not fit")
    t_d = r.time_offset
    if coarse_time_offset is not None and t_d is not None:
        moved = abs(t_d - coarse_time_offset)
        fig["clock_fine_minus_coarse_s"] = round(t_d - coarse_time_offset, 6)
        if moved > limits.clock_refinement_s:
            failed.append(f"the fit moved the clock offset {1e3 * moved:.0f} ms from the coarse "
                          f"search (plausible up to {1e3 * limits.clock_refinement_s:g} ms)")
    for name, rec in r.effects.items():
        problem = effect_problem(name, rec.get(EFFECTS[name].param), limits)
        if problem:
            failed.append(problem)
    return Plausibility(tuple(failed), PlausibilityFigures(**fig))
