"""Quality figures in calibrated units: the noise the residuals are compared with, the sigmas,
and the list of poorly determined parameters (decided on relative sigmas for the matrices and
on calibrated-unit sigmas for the biases, so a rescaled input gives the same list)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.intrinsics.multipos.fit import AccelFit, GyroFit
from mocap_calib.core.intrinsics.multipos.params import LOWER, POOR_CONDITION, POOR_SIGMA

Array = NDArray[np.float64]


def calibrated_norm_sigma(means: Array, var_mean: Array, M: Array, b: Array) -> Array:
    """1-sigma of ``|h_i|``, ``h_i = M^-1 (mean_i - b)``, from the per-axis variance of each
    mean: the accelerometer's noise in calibrated units (m/s^2)."""
    L = np.linalg.inv(M)
    h = (means - b) @ L.T
    u = h / np.linalg.norm(h, axis=1, keepdims=True)
    # var(u^T L x) = sum_c (u^T L)_c^2 var(x_c)
    v = u @ L
    return np.maximum(np.sqrt(np.sum(v * v * var_mean, axis=1)), 1e-300)


def calibrated_vector_sigma(M: Array, sigma: Array) -> Array:
    """Per-axis 1-sigma of ``M^-1 x`` for independent per-axis sigmas of ``x``."""
    L = np.linalg.inv(M)
    return np.sqrt((L * L) @ (sigma * sigma))


def gyro_noise(gyro_init: Array, offset_init: Array | float, M_g: Array, bias_sd: Array,
               rate: float) -> tuple[float, Array]:
    """White-noise density (rad/s/sqrt(Hz)) of the calibrated rate over the initial rest, and
    the bias sigma in calibrated units (rad/s)."""
    w = (gyro_init - offset_init) @ np.linalg.inv(M_g).T
    density = float(np.sqrt(np.mean(w.var(axis=0, ddof=1)) / rate))
    return density, calibrated_vector_sigma(M_g, bias_sd)


def sigmas(afit: AccelFit, gfit: GyroFit) -> tuple[Array, Array, Array]:
    """1-sigma of ``M_a`` (zero above the diagonal), ``b_a`` and ``M_g``."""
    a_sig = np.sqrt(np.clip(np.diag(afit.cov), 0.0, None))
    Ma_sig = np.zeros((3, 3))
    for k, (i, j) in enumerate(LOWER):
        Ma_sig[i, j] = a_sig[k]
    Mg_sig = np.sqrt(np.clip(np.diag(gfit.cov), 0.0, None)).reshape(3, 3)
    return Ma_sig, a_sig[6:9], Mg_sig


def _poor_matrix(name: str, M: Array, sigma: Array, lower_only: bool = False) -> list[str]:
    """Entries of ``M = diag(s) (I + E)`` whose relative sigma is large: ``sigma_ii / s_i``
    (scale) and ``sigma_ij / s_i`` (misalignment angle)."""
    out = []
    rel = sigma / np.abs(np.diag(M))[:, None]
    for i in range(3):
        for j in range(3):
            if lower_only and j > i:
                continue
            lim = POOR_SIGMA["scale"] if i == j else POOR_SIGMA["misalignment"]
            if not rel[i, j] <= lim:
                kind = "scale" if i == j else "misalignment"
                out.append(f"{name}[{i}][{j}] ({kind}, relative sigma {rel[i, j]:.2g})")
    return out


def poorly_determined(afit: AccelFit, gfit: GyroFit, Ma_sig: Array, ba_sig: Array,
                      Mg_sig: Array, bg_sd: Array) -> list[str]:
    """Parameters whose sigma is large, and ill-conditioned fits.

    Args:
        Ma_sig, ba_sig, Mg_sig, bg_sd: sigmas in the units of the fits' readings; the biases
            are judged in calibrated units.
    """
    ba_cal = calibrated_vector_sigma(afit.M, ba_sig)
    bg_cal = calibrated_vector_sigma(gfit.M, bg_sd)
    poor = _poor_matrix("accel_matrix", afit.M, Ma_sig, lower_only=True)
    poor += [f"accel_bias[{i}] (sigma {s:.2g} m/s^2)" for i, s in enumerate(ba_cal)
             if not s <= POOR_SIGMA["accel_bias"]]
    poor += _poor_matrix("gyro_matrix", gfit.M, Mg_sig)
    poor += [f"gyro_bias[{i}] (sigma {s:.2g} rad/s)" for i, s in enumerate(bg_cal)
             if not s <= POOR_SIGMA["gyro_bias"]]
    for name, cond in (("accel", afit.condition), ("gyro", gfit.condition)):
        if not cond <= POOR_CONDITION:
            poor.append(f"{name} fit ill-conditioned (condition number {cond:.2g})")
    return poor
