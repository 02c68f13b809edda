"""The simulator takes each effect's simulation from the effect registry: defaults, help, value
rules and the kind of draw are the records', and a toy effect of an existing kind registered
here is simulated (and written to the truth) with no other change."""

from __future__ import annotations

import numpy as np
import pytest

from mocap_calib.core.model.effects import EFFECTS, Effect, EffectSim
from mocap_calib.errors import InputError
from mocap_calib.sim.flight import SimConfig, simulate_flight
from mocap_calib.sim.injected import effect_help, injectable, parse_effect
from mocap_calib.sim.stream_faults import FAULTS
from tests.test_sim import QUIET, expected_imu, fast_config

TOY = Effect("toy_accel_rate_sensitivity", "accel_rate_matrix", 9, "accel", "w", "m/s^2 per rad/s",
             "a_m = M_a f + E w + b_a (an accelerometer that responds to the angular rate)",
             sim=EffectSim(1e-3, "std of the entries of E, or 9 values", "matrix",
                           non_negative=True))
TOY_E = [0.02, -0.01, 0.0, 0.005, 0.03, -0.02, 0.01, 0.0, -0.015]


def test_every_effect_has_a_simulation_record() -> None:
    for eff in EFFECTS.values():
        assert eff.sim is not None, eff.name
        assert effect_help(eff.name) == eff.sim.help
        counts = eff.sim.value_counts(eff.dim)
        assert 1 in counts and all(c in (1, 3, 6, 9) for c in counts), eff.name
    assert injectable() == (*EFFECTS, *FAULTS)


@pytest.mark.parametrize("name", list(EFFECTS))
def test_value_rules_are_the_records(name: str) -> None:
    sim = EFFECTS[name].sim
    assert sim is not None
    for n in sim.value_counts(EFFECTS[name].dim):
        values = [sim.default] if n == 1 else [0.001] * n
        assert parse_effect(f"{name}=" + ",".join(map(repr, values))) == (name, values)
    with pytest.raises(InputError, match=name):
        parse_effect(f"{name}=" + ",".join(["0.001"] * 2))  # no record accepts two values
    if sim.non_negative:
        with pytest.raises(InputError, match="negative"):
            parse_effect(f"{name}=-0.001")
    if sim.bounds is not None:
        with pytest.raises(InputError, match="between"):
            parse_effect(f"{name}={sim.bounds[1] * 2}")


def test_a_toy_effect_of_an_existing_kind_needs_only_its_record(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(EFFECTS, TOY.name, TOY)
    assert parse_effect(f"{TOY.name}") == (TOY.name, None)
    sim = simulate_flight(fast_config(effects={TOY.name: TOY_E}))
    # The conventions' model written out here: the accelerometer also sees E w.
    idx, gyro, accel = expected_imu(sim, {}, 0.0, 9.81)
    w = gyro - sim.gyro_bias_true[idx]
    E = np.reshape(TOY_E, (3, 3))
    np.testing.assert_allclose(sim.imu.accel[idx], accel + w @ E.T, rtol=0, atol=1e-4)
    np.testing.assert_allclose(sim.imu.gyro[idx], gyro, rtol=0, atol=1e-4)
    assert np.abs(w @ E.T).max() > 0.05  # the term is large against the tolerance
    assert sim.truth["effects"][TOY.name] == {"accel_rate_matrix": E.tolist()}
    assert sim.truth["model"] == f"base+{TOY.name}"
    # A bare name draws at the record's default: entries of std 1e-3.
    drawn = simulate_flight(fast_config(effects={TOY.name: None}, seed=5))
    E_drawn = np.asarray(drawn.truth["effects"][TOY.name]["accel_rate_matrix"])
    assert 1e-4 < np.abs(E_drawn).max() < 5e-3


def test_the_draws_do_not_depend_on_the_order_effects_are_given_in() -> None:
    names = ["accel_size_effect", "clock_drift", "gyro_bias_drift", "gyro_scale_misalignment",
             "mocap_outliers"]
    a = simulate_flight(SimConfig(seed=4, duration=6.0, noise=QUIET,
                                  effects={n: None for n in names}))
    b = simulate_flight(SimConfig(seed=4, duration=6.0, noise=QUIET,
                                  effects={n: None for n in reversed(names)}))
    np.testing.assert_array_equal(a.imu.accel, b.imu.accel)
    np.testing.assert_array_equal(a.mocap.position, b.mocap.position)
    assert a.truth["effects"] == b.truth["effects"]


@pytest.mark.parametrize("spec,must", [("imu_stalls=0.5,-1", "positive"),
                                       ("imu_stalls=0", "positive"),
                                       ("mocap_dropouts=2.5", "whole number"),
                                       ("imu_dropouts=-3", "negative")])
def test_fault_values_follow_their_records(spec: str, must: str) -> None:
    with pytest.raises(InputError, match=must):
        parse_effect(spec)
