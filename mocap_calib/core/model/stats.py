"""Tail probabilities and quantiles of the chi-square, F and normal distributions, from
:mod:`scipy.special` (the functions scipy.stats calls for them: the same numbers, without the
~45 MB and ~0.25 s that importing scipy.stats costs every run), and the significance of model
extensions: the chi-square tail finite far out (a likelihood-ratio statistic of a strong
effect is in the tens of thousands)."""

from __future__ import annotations

import numpy as np
from scipy import special


def chi2_sf(x: float, k: float) -> float:
    """P(chi2_k > x)."""
    return float(special.chdtrc(k, x))


def chi2_logsf(x: float, k: float) -> float:
    """log P(chi2_k > x) (-inf where it underflows; near 1 from the CDF, more exact)."""
    sf = special.chdtrc(k, x)
    with np.errstate(divide="ignore"):
        return float(np.log1p(-special.chdtr(k, x)) if sf > 0.5 else np.log(sf))


def chi2_isf(p: float, k: float) -> float:
    """x with P(chi2_k > x) = p."""
    return float(special.chdtri(k, p))


def chi2_ppf(q: float, k: float) -> float:
    """x with P(chi2_k <= x) = q."""
    return float(2.0 * special.gammaincinv(k / 2.0, q))


def chi2_median(k: float) -> float:
    return chi2_ppf(0.5, k)


def f_logsf(x: float, d1: float, d2: float) -> float:
    """log P(F_{d1, d2} > x)."""
    sf = special.fdtrc(d1, d2, x)
    with np.errstate(divide="ignore"):
        return float(np.log1p(-special.fdtr(d1, d2, x)) if sf > 0.5 else np.log(sf))


def norm_logsf(x: float) -> float:
    """log P(N(0, 1) > x), finite far into the tail."""
    return float(special.log_ndtr(-x))


def log10_chi2_sf(t: float, k: int) -> float:
    """log10 P(chi2_k > t), finite far into the tail (Wilson-Hilferty when scipy underflows)."""
    lp = chi2_logsf(t, k)
    if np.isfinite(lp):
        return lp / np.log(10.0)
    z = ((t / k) ** (1.0 / 3.0) - (1.0 - 2.0 / (9.0 * k))) / np.sqrt(2.0 / (9.0 * k))
    return norm_logsf(z) / np.log(10.0)
