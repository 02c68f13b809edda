"""The checks after the fit: one-step refits against full ones, the plausibility gate, the
clock search's refusals."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mocap_calib.core.model import so3
from mocap_calib.core.model.parameters import ROTATION, TIME_OFFSET, TRANSLATION
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.core.uncertainty.segments import segment_consistency
from mocap_calib.core.uncertainty.sensitivity import noise_sensitivity
from mocap_calib.errors import ObservabilityError, PlausibilityError
from mocap_calib.sim.flight import SimConfig, simulate_flight

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset


@pytest.fixture(scope="module")
def calibrated():
    sim = simulate_flight(SimConfig(seed=41, duration=60.0, effects={"time_offset": [0.004]},
                                    mocap_noise_corr=0.2))
    res = calibrate(sim.imu, sim.mocap, CalibrationOptions(segments=0,
                                                           sensitivity=False))
    return sim, res


def test_one_step_refits_match_full_refits(calibrated) -> None:
    """Segments take one Gauss-Newton step from the full solution: it must land where LM to
    convergence does (to a small fraction of a sigma)."""
    _, res = calibrated
    tr = res.diagnostics.trace
    model, pos = tr.model_state.model, tr.position
    one = segment_consistency(pos, model, 3)
    full = segment_consistency(pos, model, 3, one_step=False)
    for a, b in zip(one.segments, full.segments, strict=True):
        a, b = a.est, b.est
        assert np.all(np.abs(so3.log(a.R_MI.T @ b.R_MI)) < 0.05 * b.sigma[ROTATION])
        assert np.all(np.abs(a.p_MI - b.p_MI) < 0.05 * b.sigma[TRANSLATION])
        assert abs(a.t_d - b.t_d) < 0.05 * b.sigma[TIME_OFFSET][0]
        # The sigmas include the sandwich over the segment's few windows (20 s: four blocks),
        # which moves with the linearisation point more than the estimate does.
        np.testing.assert_allclose(a.sigma[TRANSLATION], b.sigma[TRANSLATION], rtol=0.25)


def _moves(tr, alt) -> dict:
    """How far ``alt`` lands from the trace's solution, in its statistical sigmas."""
    s, pos, a = tr.session, tr.position, alt.position
    sig = {p: np.sqrt(np.diag(pos.cov[p.name])) for p in (ROTATION, TRANSLATION, TIME_OFFSET)}
    return {ROTATION: np.max(np.abs(so3.log(pos.R_MI.T @ a.R_MI)) / sig[ROTATION]),
            TRANSLATION: np.max(np.abs(a.p_MI - pos.p_MI) / sig[TRANSLATION]),
            TIME_OFFSET: abs((a.delta - alt.session.clock_shift)
                             - (pos.delta - s.clock_shift)) / sig[TIME_OFFSET][0]}


def test_noise_sensitivity_lands_where_a_rerun_does(calibrated) -> None:
    """With the densities held as given (--fixed-noise), the sensitivity section claims how
    far a user's rerun with the IMU noise densities x3 or x1/3 would move the answer: reruns
    from scratch (clock search, stages, robust weights and mocap noise chosen anew) must move
    by what it says, to a quarter of a sigma."""
    sim, _ = calibrated
    fixed = CalibrationOptions(segments=0, sensitivity=False, noise_from_data=False)
    tr = calibrate(sim.imu, sim.mocap, fixed).diagnostics.trace
    sens = noise_sensitivity(tr.position, tr.model_state.model, mocap_model=False)
    for f, key in ((3.0, "x3"), (1.0 / 3.0, "x0.333")):
        alt = calibrate(sim.imu, sim.mocap, replace(fixed, noise=NoiseModel().imu_scaled(f)))
        for k, v in _moves(tr, alt.diagnostics.trace).items():
            assert sens.moved[key][k] == pytest.approx(v, abs=0.25 + 0.1 * v), (key, k)


def test_identified_noise_does_not_follow_the_densities_given(calibrated) -> None:
    """By default the levels come from the data: a rerun given densities x3 or x1/3 lands
    close to where the first run did (the given ones only centre a weak prior), and within what
    the run's own noise-sensitivity term claims (it scales the identified levels themselves).
    Measured: at most 0.39 statistical sigma (t_d at x3: the gyro's level, which the mocap's
    attitude noise hides here, stays near the one given), where the term claims 0.67."""
    sim, res = calibrated
    tr = res.diagnostics.trace
    assert res.noise_identification is not None and res.noise_identification.used
    sens = noise_sensitivity(tr.position, tr.model_state.model, mocap_model=False)
    for f, key in ((3.0, "x3"), (1.0 / 3.0, "x0.333")):
        alt = calibrate(sim.imu, sim.mocap, CalibrationOptions(
            noise=NoiseModel().imu_scaled(f), segments=0, sensitivity=False))
        for k, v in _moves(tr, alt.diagnostics.trace).items():
            assert v < 0.5, (f, k, v)
            assert v <= sens.moved[key][k] + 0.1, (f, k, v, sens.moved[key][k])


def test_implausible_answer_exits_4_or_is_marked() -> None:
    """An accel bias of 3 m/s^2 (far beyond a MEMS part's) is refused, and with the user's
    consent written with the verdict."""
    sim = simulate_flight(SimConfig(seed=42, duration=40.0, effects={"time_offset": [0.003],
                                                                      "accel_bias_drift": [0.0]}))
    imu = sim.imu
    biased = type(imu)(imu.t, imu.gyro, imu.accel + np.array([3.0, 0.0, 0.0]),
                       imu.time_origin_ns, imu.source)
    opts = CalibrationOptions(segments=0, sensitivity=False)
    with pytest.raises(PlausibilityError, match=r"accel bias of [23]\.\d+ m/s\^2"):
        calibrate(biased, sim.mocap, opts)
    res = calibrate(biased, sim.mocap, CalibrationOptions(segments=0,
                                                          sensitivity=False,
                                                          accept_implausible=True))
    assert res.plausibility.verdict == "implausible"
    assert any("IMPLAUSIBLE" in n for n in res.notes)
    clean = calibrate(sim.imu, sim.mocap, opts)
    assert clean.plausibility.verdict == "plausible" and clean.plausibility.failed == ()


def test_periodic_motion_clock_is_refused_unless_the_range_is_limited() -> None:
    """A flight that repeats every 4 s: lags 4 s apart fit equally well. Exit 3 naming the
    candidates; --max-offset within one period resolves it."""
    sim = simulate_flight(SimConfig(seed=1, duration=60.0, effects={"time_offset": [0.004]},
                                    periodic_motion_s=4.0))
    opts = CalibrationOptions(segments=0, sensitivity=False)
    with pytest.raises(ObservabilityError, match="cannot resolve the clock offset.*--max-offset"):
        calibrate(sim.imu, sim.mocap, opts)
    res = calibrate(sim.imu, sim.mocap, CalibrationOptions(max_offset=1.0,
                                                           segments=0,
                                                           sensitivity=False))
    assert res.time_offset == pytest.approx(0.004, abs=3e-4)


@pytest.mark.parametrize("t_d", [-0.004, -0.037])
def test_translation_only_session_aligns_by_specific_force(t_d: float) -> None:
    """Almost no rotation (BROAD 15's kind of session): angular speed alone cannot align the
    clocks, specific force can. The coarse search lands 2.0 ms from the truth on both offsets
    (the fine fit does the rest); 2.5 ms is a tolerance a search returning 0 fails."""
    sim = simulate_flight(SimConfig(seed=43, duration=60.0, effects={"time_offset": [t_d]}))
    from mocap_calib.core.clock.search import search_clock
    from mocap_calib.core.prepare.session import prepare

    s = prepare(sim.imu, sim.mocap)
    # Keep the accelerometer, flatten the rotation signal: the gyro then tells nothing.
    still = np.tile(np.median(s.gyro, axis=0), (len(s.u), 1))
    found = search_clock(s.u, still, s.accel, s.tau, np.broadcast_to(s.R_WM[0], s.R_WM.shape),
                         s.p_WM, s.clock_shift)
    assert found.signals == ("specific force (+z up)",)
    assert found.resolved and found.time_offset == pytest.approx(t_d, abs=2.5e-3)
