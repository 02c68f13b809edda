"""A calibration's refits (effect tests, segments, sensitivity) release their engines: nothing
of a finished position graph outlives it (memory flat in the session length).

The position graph's C++ factors hold Python callbacks; a callback that held the graph back
made a cycle the collector cannot see, and every refit's window arrays lived until the process
ended (30 min: 885 MB peak, 683 MB without the cycle)."""

from __future__ import annotations

import gc

from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.core.position.engine import PositionProblem
from mocap_calib.sim.flight import SimConfig, simulate_flight


def _alive() -> int:
    gc.collect()
    return sum(isinstance(o, PositionProblem) for o in gc.get_objects())


def test_no_engine_outlives_a_calibration() -> None:
    before = _alive()
    sim = simulate_flight(SimConfig(seed=3, duration=40.0, effects={"time_offset": [0.003]}))
    res = calibrate(sim.imu, sim.mocap, CalibrationOptions())
    assert res.sensitivity and res.consistency  # the refits ran
    del res
    assert _alive() == before
