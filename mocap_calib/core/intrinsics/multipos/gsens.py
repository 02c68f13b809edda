"""The gyro's g-sensitivity ``G`` (effect ``gyro_g_sensitivity``: ``w_m = M_g w + G f + b_g``)
from the static poses, and whether the data need it.

At rest ``w = 0``, so every static interval ``i`` observes ``mean_i(w_m) = b_g + G f_i`` with
``f_i`` the calibrated specific force (gravity, ``|f_i| = g``). Per gyro axis this is a linear
regression on ``[1, f_i]`` weighted by the noise of each interval mean; without ``G`` it is the
weighted mean. The two are compared as ``diagnose`` compares models: a likelihood-ratio test
``T = (chi2_without - chi2_with) / s^2`` against ``chi2_9``, with ``s^2 = max(1, chi2/dof)`` of
the fit with ``G`` absorbing a misjudged noise level (e.g. a slowly wandering bias).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.stats import log10_chi2_sf

Array = NDArray[np.float64]

#: False-alarm rate of the test.
ALPHA = 0.01


@dataclass(frozen=True)
class GSensitivityFit:
    """``G`` and the bias from the static poses, and the test of ``G`` against none.

    Attributes:
        G: (3, 3) rad/s per m/s^2 (in the units of the gyro readings given).
        G_sigma: (3, 3) 1-sigma.
        bias: (3,) ``b_g`` with ``G`` in the model (the intercept).
        bias_sigma: (3,) its 1-sigma.
        chi2_without: weighted residual sum of squares without ``G``.
        chi2_with: same with ``G``.
        dof: degrees of freedom with ``G``.
        statistic: the noise-scaled likelihood-ratio statistic ``T``.
        log10_p: log10 of its p-value under "no g-sensitivity" (chi-square, 9 dof).
        significant: ``log10_p < log10(ALPHA)``.
    """

    G: Array
    G_sigma: Array
    bias: Array
    bias_sigma: Array
    chi2_without: float
    chi2_with: float
    dof: int
    statistic: float
    log10_p: float
    significant: bool

    def test_dict(self) -> dict[str, Any]:
        return {"test": "likelihood ratio, noise-scaled (as diagnose), 9 dof",
                "chi2_without": float(self.chi2_without), "chi2_with": float(self.chi2_with),
                "dof": int(self.dof), "statistic": float(self.statistic),
                "log10_p": float(self.log10_p), "alpha": ALPHA,
                "significant": bool(self.significant)}


def fit_g_sensitivity(gyro_means: Array, gyro_sigma: Array, f: Array) -> GSensitivityFit | None:
    """Regress the static gyro means on the specific force.

    Args:
        gyro_means: (n, 3) mean gyro of each static interval.
        gyro_sigma: (n, 3) 1-sigma of those means.
        f: (n, 3) calibrated specific force of each interval, m/s^2.

    Returns:
        The fit and its test; None with fewer than 5 intervals (4 parameters per axis).
    """
    n = len(gyro_means)
    if n < 5:
        return None
    A = np.hstack([np.ones((n, 1)), f])
    G = np.zeros((3, 3))
    G_sig = np.zeros((3, 3))
    bias = np.zeros(3)
    bias_sig = np.zeros(3)
    chi2_with = chi2_without = 0.0
    covs = []
    for c in range(3):
        w = 1.0 / gyro_sigma[:, c] ** 2
        N = A.T @ (A * w[:, None])
        cov = np.linalg.inv(N)
        coef = cov @ (A.T @ (w * gyro_means[:, c]))
        chi2_with += float(np.sum(w * (gyro_means[:, c] - A @ coef) ** 2))
        mean = float(np.sum(w * gyro_means[:, c]) / np.sum(w))
        chi2_without += float(np.sum(w * (gyro_means[:, c] - mean) ** 2))
        bias[c], G[c] = coef[0], coef[1:]
        covs.append(cov)
    dof = 3 * n - 12
    scale = max(1.0, chi2_with / dof) if dof > 0 else 1.0
    for c in range(3):
        sd = np.sqrt(np.clip(np.diag(covs[c]) * scale, 0.0, None))
        bias_sig[c], G_sig[c] = sd[0], sd[1:]
    stat = max(chi2_without - chi2_with, 0.0) / scale
    log10_p = log10_chi2_sf(stat, 9)
    return GSensitivityFit(G, G_sig, bias, bias_sig, chi2_without, chi2_with, dof, stat,
                           log10_p, log10_p < np.log10(ALPHA))


def interval_gyro_means(gyro: Array, iv: NDArray[np.int64]) -> tuple[Array, Array]:
    """Mean gyro of each interval and its 1-sigma (the larger of the white-noise estimate and
    the scatter of 10 block means, which catches correlated noise)."""
    means = np.empty((len(iv), 3))
    sig = np.empty((len(iv), 3))
    for k, (a, b) in enumerate(iv):
        x = gyro[a:b + 1]
        means[k] = x.mean(axis=0)
        white = x.std(axis=0, ddof=1) / np.sqrt(len(x))
        blk = len(x) // 10
        if blk >= 2:
            blocks = x[:10 * blk].reshape(10, blk, 3).mean(axis=1)
            white = np.maximum(white, blocks.std(axis=0, ddof=1) / np.sqrt(10))
        # Floor for noise-free (synthetic or quantised) data, relative so units do not matter.
        sig[k] = np.maximum(white, 1e-12 * (float(np.max(np.abs(x))) + 1e-300))
    return means, sig
