"""Never a plausibility verdict on a quantity the result reports as undetermined: a mocap
world tilted beyond the limit is refused when the session determines the gravity direction,
and not judged when it does not (its sigma beyond use), as on a flight that barely rotates."""

from __future__ import annotations

import numpy as np
import pytest

from mocap_calib.core.checks.degenerate import mark_undetermined
from mocap_calib.core.checks.verdict import plausibility_gate
from mocap_calib.core.model.parameters import (
    ACCEL_BIAS,
    GRAVITY_DIRECTION,
    GYRO_BIAS,
    ROTATION,
    TIME_OFFSET,
    TRANSLATION,
)
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.result.estimate import Estimate
from mocap_calib.errors import PlausibilityError


def _result(gravity_sigma_deg: float, accel_bias_sigma: float) -> CalibrationResult:
    tilt = np.radians(6.0)  # beyond the 5 deg a mocap world is plausibly tilted
    g = np.array([np.sin(tilt), 0.0, -np.cos(tilt)])
    est = {
        GYRO_BIAS: Estimate.of(GYRO_BIAS, [1e-3, 0, 0], [1e-4] * 3),
        ACCEL_BIAS: Estimate.of(ACCEL_BIAS, [0.05, 0, 0], [accel_bias_sigma] * 3),
        ROTATION: Estimate.of(ROTATION, [1.0, 0, 0, 0], [1e-3] * 3),
        TRANSLATION: Estimate.of(TRANSLATION, [0.01, 0.02, 0.0], [1e-3] * 3),
        GRAVITY_DIRECTION: Estimate.of(GRAVITY_DIRECTION, g,
                                       [np.radians(gravity_sigma_deg)] * 2),
        TIME_OFFSET: Estimate.of(TIME_OFFSET, 0.004, 1e-4),
    }
    return CalibrationResult(estimates=est)


def test_a_determined_tilt_beyond_the_limit_is_refused() -> None:
    r = mark_undetermined(_result(gravity_sigma_deg=0.1, accel_bias_sigma=0.01))
    with pytest.raises(PlausibilityError, match="tilted 6.0 deg"):
        plausibility_gate(r, CalibrationOptions(), None, None)


def test_an_undetermined_tilt_is_not_judged() -> None:
    r = mark_undetermined(_result(gravity_sigma_deg=5.3, accel_bias_sigma=0.7))
    assert GRAVITY_DIRECTION.name in r.unobservable and ACCEL_BIAS.name in r.unobservable
    judged = plausibility_gate(r, CalibrationOptions(), None, None)
    assert judged.plausibility is not None and not judged.plausibility.failed
    assert "tilt_deg" not in judged.plausibility.to_dict().get("figures", {})
