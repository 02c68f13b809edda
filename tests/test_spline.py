"""The pose series' spline against scipy's ``CubicSpline`` (not-a-knot), bit for bit: values
and derivatives inside, at the knots, between them and beyond the ends."""

from __future__ import annotations

import numpy as np
import pytest
from loaded import loaded_by
from scipy.interpolate import CubicSpline as ScipySpline

from mocap_calib.core.diagnosis.spline import CubicSpline


@pytest.mark.parametrize("n", [4, 5, 37, 2000])
def test_the_spline_is_scipys(n: int) -> None:
    rng = np.random.default_rng(n)
    x = np.cumsum(rng.uniform(0.005, 0.015, n))  # uneven steps, as mocap stamps
    y = np.column_stack([np.sin(3 * x), np.cos(x), x**2, rng.normal(size=n)])
    t = np.concatenate([x, rng.uniform(x[0] - 0.05, x[-1] + 0.05, 500), [x[0], x[-1]]])
    ours, ref = CubicSpline(x, y), ScipySpline(x, y, axis=0)
    for nu in range(4):
        np.testing.assert_array_equal(ours(t, nu), ref(t, nu))
    assert np.isnan(ours(np.array([np.nan]), 1)).all()


def test_a_spline_refuses_what_it_cannot_fit() -> None:
    with pytest.raises(ValueError, match="four points"):
        CubicSpline(np.arange(3.0), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="increasing"):
        CubicSpline(np.array([0.0, 1.0, 1.0, 2.0]), np.zeros((4, 2)))


def test_the_diagnosis_imports_no_scipy_interpolate() -> None:
    code = "import mocap_calib.workflows.diagnose, mocap_calib.core.diagnosis.predict"
    assert loaded_by(code, ["scipy.interpolate", "scipy.optimize"]) == []
