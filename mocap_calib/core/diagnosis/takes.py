"""Several takes in one diagnosis: what the takes' fits share and combine, and whether an
effect found jointly holds in each take.

The diagnosis fits every take together (shared ``T_MI``, gravity and effects; each take its
own clock offset and biases, as ``calibrate``). An effect the joint test finds is then tested
in each take alone at the joint solution (its score test with that take's parameters, shared
ones included, re-optimised to first order): each take's own test (``evidence``: significant
at the step's threshold) and one-step estimate are reported, and the takes' estimates must
agree (a homogeneity chi-square, the inverse-variance mean against each take's) for the effect
to count as found. An effect each take has its own value of (the clock offset) is not tested
for agreement.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.diagnosis.predict import ResidualAnalysis
from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.position.stage import Memo, PositionResult
from mocap_calib.core.result.state import ModelState

Array = NDArray[np.float64]


def take_result(pos: PositionResult, k: int) -> PositionResult:
    """A joint fit seen as take ``k``'s alone (the shared values, that take's own; none of
    what was computed from the joint fit and kept with it)."""
    return replace(pos, takes=[pos.takes[k]], memo=Memo())


def take_state(pos: PositionResult, k: int, model: Model, t_mid: float) -> ModelState:
    """The model state of take ``k`` of a joint fit."""
    return ModelState.from_position(take_result(pos, k), model, t_mid)


def combine_rms(analyses: list[ResidualAnalysis]) -> tuple[Array, Array, Array, Array]:
    """Low-band residual RMS and floors of the takes together (mean square over the takes,
    weighted by their lengths): gyro rms, gyro floor, accel rms, accel floor."""
    w = np.array([max(len(a.t), 1) for a in analyses], dtype=float)
    w /= w.sum()

    def ms(name: str) -> Array:
        return np.sqrt(sum(wk * np.asarray(getattr(a, name)) ** 2
                           for wk, a in zip(w, analyses, strict=True)))

    return ms("gyro_rms"), ms("gyro_floor"), ms("accel_rms"), ms("accel_floor")


def homogeneity(values: list[Array], covs: list[Array]) -> tuple[float, int]:
    """Chi-square of the takes' estimates of an effect about their inverse-variance mean, and
    its degrees of freedom ((takes - 1) x the effect's dimension)."""
    x = [np.atleast_1d(v) for v in values]
    info = [np.linalg.pinv(np.atleast_2d(c)) for c in covs]
    mean = np.linalg.solve(sum(info), sum(i @ v for i, v in zip(info, x, strict=True)))
    q = float(sum((v - mean) @ i @ (v - mean) for i, v in zip(info, x, strict=True)))
    return q, (len(values) - 1) * len(mean)


def evidence_row(k: int, log10_p: float, threshold: float, params: Any,
                 sigma: Any) -> dict[str, Any]:
    """What the report says of one take's own test of an effect."""
    return {"take": k + 1, "log10_p": round(float(log10_p), 3),
            "evidence": bool(log10_p < threshold), "value": params, "sigma": sigma}


def shared(effect: str) -> bool:
    """Whether the takes share the effect's value (the clock offset is each take's own)."""
    return EFFECTS[effect].acts_on != "clock"


def stamps_disjoint(recordings: list[Any], t_d: float) -> bool:
    """Whether some take's (a recording's) raw IMU and mocap stamps, the IMU's shifted by
    ``t_d``, share no instant: a model without the clock offset cannot be calibrated then."""
    for r in recordings:
        shift = (r.mocap.time_origin_ns - r.imu.time_origin_ns) * 1e-9  # mocap t on IMU clock
        lo = max(r.imu.t[0] + t_d, r.mocap.t[0] + shift)
        hi = min(r.imu.t[-1] + t_d, r.mocap.t[-1] + shift)
        if hi <= lo:
            return True
    return False
