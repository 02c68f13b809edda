"""A marker set flipped for a stretch of the session (the mocap matched a symmetric rigid
body's markers the wrong way round) is named as such, with where, whatever its length; before,
a one-second flip passed with every noise level inflated (exit 0) and longer ones were blamed
on the clock."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mocap_calib.core.model import so3
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.core.prepare.pose_flips import flips
from mocap_calib.errors import InputError
from mocap_calib.sim.flight import SimConfig, simulate_flight


@pytest.fixture(scope="module")
def sim():
    return simulate_flight(SimConfig(seed=5, duration=40.0, effects={"time_offset": [0.004]}))


def _flipped(sim, t1: float, t2: float):
    m = sim.mocap
    R = m.rotation.copy()
    rows = (m.t >= t1) & (m.t < t2)
    R[rows] = R[rows] @ so3.exp(np.array([np.pi, 0.0, 0.0]))
    return replace(m, quat_wxyz=so3.rotmat_to_quat(R))


@pytest.mark.parametrize(("t1", "t2", "named"), [
    (10.0, 11.0, r"flips between two poses at 9\.9\d-10\.0\d s \(1\d\d deg\), "
                 r"10\.9\d-11\.0\d s .* stays turned for 1\.0\d s"),
    (10.0, 30.0, r"at 9\.9\d-10\.0\d s \(1\d\d deg\), 29\.9\d-30\.0\d s .* turned for 20"),
    (10.0, 99.0, r"at 9\.9\d-10\.0\d s \(1\d\d deg\) of the mocap log; it stays turned to "
                 r"the end")])
def test_a_flipped_marker_set_is_named(sim, t1: float, t2: float, named: str) -> None:
    with pytest.raises(InputError, match=named):
        calibrate(sim.imu, _flipped(sim, t1, t2), CalibrationOptions(segments=0,
                                                                      sensitivity=False))


def test_fast_turns_and_turns_across_dropouts_are_not_flips(sim) -> None:
    m = sim.mocap
    assert len(flips(m.t, m.rotation)) == 0  # an aggressive flight
    # 120 deg across a 2 s hole: a body can turn that far (at 1 rad/s).
    t = np.array([0.0, 0.01, 2.01, 2.02])
    R = so3.exp(np.array([[0, 0, 0], [0, 0, 0.05], [0, 0, 2.1], [0, 0, 2.15]]))
    assert len(flips(t, R)) == 0
    R2 = so3.exp(np.array([[0, 0, 0], [0, 0, 0.05], [0, 0, 2.1], [0, 0, 2.15]]))
    t2 = np.array([0.0, 0.01, 0.02, 0.03])  # the same 118 deg in one frame: a flip
    assert list(flips(t2, R2)) == [1]
