"""What a stage reports: its figures (residual RMS before and after, iterations, time) and its
residual series over time, for inspection."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@dataclass
class StageStats:
    """Figures of one stage.

    Attributes:
        name: ``attitude``, ``velocity`` or ``position``.
        unit: unit of the residuals (per axis).
        rms_before, rms_after: residual RMS per axis before / after the stage's solve (all
            residuals, as in the residual series).
        rms_after_inliers: the same without the residuals the robust kernel down-weighted.
        rms_rotation_deg: for the position stage, the attitude part of the residuals.
        n_factors: number of factors (intervals or windows).
        n_residuals: number of residual vectors (intervals or mocap samples).
        outliers: residuals down-weighted by the robust kernel (weight < 0.5).
        iterations: LM iterations; seconds: wall time of the stage.
        chi2_per_dof: whitened cost per degree of freedom at the solution (1 = noise as modelled).
    """

    name: str
    unit: str
    rms_before: list[float]
    rms_after: list[float]
    n_factors: int
    n_residuals: int
    outliers: int
    iterations: int
    seconds: float
    chi2_per_dof: float
    rms_rotation_deg: list[float] | None = None
    rms_after_inliers: list[float] | None = None
    batch_evaluations: int = 0

    def to_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in self.__dict__.items() if v is not None}
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StageStats:
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})


@dataclass
class ResidualSeries:
    """Residuals of one stage over time, for inspection (not written to YAML).

    Attributes:
        t: (n,) mocap-clock times (s since the mocap origin).
        before, after: (n, 3) residuals before / after the solve, in ``unit``.
        weight: (n,) robust weights at the solution (1 = inlier).
        unit: unit of the residuals.
        rotation_before, rotation_after: (n, 3) attitude residuals (deg) of the position stage.
    """

    t: Array
    before: Array
    after: Array
    weight: Array
    unit: str
    rotation_before: Array | None = None
    rotation_after: Array | None = None
