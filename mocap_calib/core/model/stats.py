"""Significance of model extensions: the tail of the chi-square distribution, finite far out
(a likelihood-ratio statistic of a strong effect is in the tens of thousands)."""

from __future__ import annotations

import numpy as np
from scipy import stats


def log10_chi2_sf(t: float, k: int) -> float:
    """log10 P(chi2_k > t), finite far into the tail (Wilson-Hilferty when scipy underflows)."""
    lp = float(stats.chi2.logsf(t, k))
    if np.isfinite(lp):
        return lp / np.log(10.0)
    z = ((t / k) ** (1.0 / 3.0) - (1.0 - 2.0 / (9.0 * k))) / np.sqrt(2.0 / (9.0 * k))
    return float(stats.norm.logsf(z) / np.log(10.0))
