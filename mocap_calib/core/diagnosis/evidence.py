"""The diagnosis' evidence in numbers: chi-square tails far into the tail, and which sensor an
effect acts on and how much a fit lowered its low-band residual."""

from __future__ import annotations

import numpy as np
from scipy import special

from mocap_calib.core.diagnosis.report import Residuals
from mocap_calib.core.model.effects import EFFECTS
from mocap_calib.core.model.stats import chi2_logsf


def log10_sf(t: float, k: int) -> float:
    """log10 P(chi2_k > t), finite far into the tail.

    Where scipy underflows (t beyond about 1400) the upper incomplete gamma's asymptotic series
    takes over: Q(a, x) = x^(a-1) e^-x / Gamma(a) * (1 + (a-1)/x + (a-1)(a-2)/x^2 + ...), with
    a = k/2 << x = t/2, so a few terms are exact to double precision (Wilson-Hilferty is off
    by hundreds of decades there for 1 dof: it ranks a 1-dof effect with T = 4562 below one
    with T = 1142)."""
    lp = float(chi2_logsf(t, k))
    if np.isfinite(lp):
        return lp / np.log(10.0)
    a, x = 0.5 * k, 0.5 * t
    series, term = 1.0, 1.0
    for n in range(1, 8):
        term *= (a - n) / x
        series += term
    return float(((a - 1.0) * np.log(x) - x - special.gammaln(a)
                  + np.log(series)) / np.log(10.0))


def sensor_of(effect: str) -> str:
    """The sensor whose residual an effect acts on: gyro, accel or both."""
    e = EFFECTS[effect]
    if e.sensor in ("gyro", "accel"):
        return e.sensor
    return "accel" if e.acts_on == "gravity" else "both"


def residual_drop(before: Residuals, after: Residuals, sensor: str) -> float:
    """Relative drop of the low-band residual over floor on ``sensor`` (both: the larger)."""
    if sensor == "both":
        return max(residual_drop(before, after, "gyro"), residual_drop(before, after, "accel"))
    return 1.0 - after.ratio(sensor) / before.ratio(sensor)
