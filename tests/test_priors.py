"""Priors from earlier calibrations: one result, and a trend from several."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mocap_calib.core.model import so3
from mocap_calib.core.model.parameters import TRANSLATION
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.core.result.priors import priors_from_results
from mocap_calib.errors import InputError
from mocap_calib.sim.flight import SimConfig, simulate_flight

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

RIG = 77


def _errors(res, truth) -> tuple[float, float]:
    R_t = so3.quat_to_rotmat(np.array(truth["T_marker_imu"]["rotation_wxyz"]))
    rot = np.degrees(np.linalg.norm(so3.log(R_t.T @ so3.quat_to_rotmat(res.rotation_wxyz))))
    trans = float(np.linalg.norm(res.translation - np.array(truth["T_marker_imu"]["translation"])))
    return float(rot), trans


def test_prior_from_an_earlier_session_shortens_the_session_needed() -> None:
    earlier = simulate_flight(SimConfig(seed=1, duration=90.0, rig_seed=RIG))
    prior_res = calibrate(earlier.imu, earlier.mocap, CalibrationOptions())
    priors = priors_from_results([prior_res])
    assert {p.block for p in priors} >= {"rotation", "translation", "gravity"}
    assert not {p.block for p in priors} & {"gyro_bias", "accel_bias", "time_offset"}

    short = simulate_flight(SimConfig(seed=2, duration=12.0, rig_seed=RIG,
                                      effects={"time_offset": [0.003]}))
    longer = simulate_flight(SimConfig(seed=3, duration=90.0, rig_seed=RIG,
                                       effects={"time_offset": [0.003]}))
    alone = calibrate(short.imu, short.mocap, CalibrationOptions())
    with_prior = calibrate(short.imu, short.mocap, CalibrationOptions(priors=priors))
    reference = calibrate(longer.imu, longer.mocap, CalibrationOptions())
    # The 12 s session with the prior is as precise as 90 s without one; alone it is not.
    for name in ("sigma_rotation", "sigma_translation", "sigma_gravity"):
        assert getattr(with_prior, name).max() < 1.5 * getattr(reference, name).max(), name
        assert getattr(alone, name).max() > 2.0 * getattr(with_prior, name).max(), name
    # ... and as accurate, with honest sigmas (errors against the simulator's truth).
    R_t = so3.quat_to_rotmat(np.array(short.truth["T_marker_imu"]["rotation_wxyz"]))
    d_rot = so3.log(R_t.T @ so3.quat_to_rotmat(with_prior.rotation_wxyz))
    d_p = with_prior.translation - np.array(short.truth["T_marker_imu"]["translation"])
    assert np.all(np.abs(d_rot) < 4 * with_prior.sigma_rotation)
    assert np.all(np.abs(d_p) < 4 * with_prior.sigma_translation)
    e_prior = _errors(with_prior, short.truth)
    assert e_prior[0] < 0.05 and e_prior[1] < 2e-3  # 0.05 deg, 2 mm


def test_trend_from_two_results_extrapolates_to_the_new_session() -> None:
    """Two earlier results whose lever arm moved by 2 mm per day: the prior for a session a
    day later is the extrapolated value, with a sigma that grows with the extrapolation."""
    r1 = calibrate(*_streams(4), CalibrationOptions())
    r2 = calibrate(*_streams(5), CalibrationOptions())
    day = 86400 * 10**9
    r1.session["imu_start_ns"] = 0
    r2.session["imu_start_ns"] = day
    moved = replace(r1.estimate(TRANSLATION), value=r1.translation + np.array([0.0, 0.0, -0.002]))
    r1 = r1.with_estimates({TRANSLATION: moved})
    priors = {p.block: p for p in priors_from_results([r1, r2], at_ns=2 * day)}
    p = priors["translation"]
    expected = r2.translation + (r2.translation - r1.translation)
    np.testing.assert_allclose(p.value, expected, atol=1e-9)
    assert np.all(p.sigma > r2.sigma_translation)
    with pytest.raises(InputError):
        priors_from_results([r1, r2])  # a trend needs the new session's time


def _streams(seed: int):
    sim = simulate_flight(SimConfig(seed=seed, duration=30.0, rig_seed=RIG))
    return sim.imu, sim.mocap
