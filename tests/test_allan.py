"""Allan-deviation noise characterisation on simulated static logs with known noise."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from mocap_calib.core.intrinsics.allan import characterise_noise
from mocap_calib.core.model.types import ImuSamples, NoiseModel
from mocap_calib.errors import InputError, ObservabilityError
from mocap_calib.sim.static import simulate_static

KALIBR = ("gyroscope_noise_density", "gyroscope_random_walk",
          "accelerometer_noise_density", "accelerometer_random_walk")

# Durations. The random walk K is the hard part: its precision depends only on how many
# crossover times tau_c = sqrt(3) N / K the log spans (EuRoC's ADIS16448: gyro tau_c = 15 s,
# accel 1.2 s), not on the sample rate. In a 40-seed Monte Carlo of 6 h logs the gyro K
# (mean over axes) had a 2.1 % standard deviation and a worst case of 8.3 %; with 2 h it was
# 4.3 % and 14 %. So 6 h makes "within 10 %" a > 4-sigma test. The white noise N is good to
# ~0.1 % at any rate, so 20 Hz keeps the test fast (430 k samples, ~0.4 s per log).
DURATION_S = 6 * 3600.0
RATE_HZ = 20.0


@cache
def _log(seed: int) -> tuple[ImuSamples, dict]:
    return simulate_static(seed, DURATION_S, RATE_HZ)


@pytest.mark.parametrize("seed", [0, 1])
def test_white_noise_and_random_walk_within_10_percent(seed: int) -> None:
    imu, truth = _log(seed)
    res = characterise_noise(imu)
    d = res.to_dict()
    for key in KALIBR:
        assert d[key] == pytest.approx(truth[key], rel=0.10), key
    # Per axis too: the white noise is very well determined.
    for s, name in ((res.gyroscope, "gyroscope"), (res.accelerometer, "accelerometer")):
        assert np.allclose(s.noise_density, truth[f"{name}_noise_density"], rtol=0.02)
        assert np.all(s.random_walk_resolved)
        assert np.all(np.abs(s.random_walk / truth[f"{name}_random_walk"] - 1) < 0.2)
        assert np.all(s.fit_chi2 < 4.0)
    assert "unobservable" not in d


def test_bias_instability_of_a_flicker_floor() -> None:
    """A clear flicker floor (white noise reaches it at ~10 s, random walk only beyond the
    log) is read within 20 % from the fitted curve's minimum and within 15 % from the fit."""
    noise = NoiseModel(gyroscope_noise_density=1e-4, gyroscope_random_walk=1e-7,
                       accelerometer_noise_density=1e-3, accelerometer_random_walk=1e-6)
    B = (5e-5, 5e-4)
    imu, _ = simulate_static(3, 3 * 3600.0, RATE_HZ, noise=noise, bias_instability=B)
    res = characterise_noise(imu, require_random_walk=False)
    for s, b, n in ((res.gyroscope, B[0], 1e-4), (res.accelerometer, B[1], 1e-3)):
        assert np.allclose(s.bias_instability, b, rtol=0.2)
        assert np.allclose(s.bias_instability_fit, b, rtol=0.15)
        assert np.allclose(s.noise_density, n, rtol=0.05)
    d = res.to_dict()
    assert len(d["gyroscope_bias_instability"]) == 3
    assert np.asarray(d["allan"]["gyroscope"]["adev"]).shape == (3, len(res.gyroscope.tau))


def test_to_dict_layout() -> None:
    imu, _ = _log(0)
    res = characterise_noise(imu, aggregate="max")
    d = res.to_dict()
    assert set(KALIBR) <= set(d) and d["update_rate"] == pytest.approx(RATE_HZ)
    assert d["aggregate"] == "max"
    assert d["gyroscope_noise_density"] == pytest.approx(float(np.max(
        res.gyroscope.noise_density)))
    assert {"gyroscope", "accelerometer"} == set(d["per_axis"]) == set(d["allan"])
    tau = np.asarray(d["allan"]["accelerometer"]["tau"])
    assert np.all(np.diff(np.log2(tau)) == pytest.approx(1.0))  # octave spacing


def test_too_short_for_the_random_walk_says_how_long() -> None:
    # A gyro whose random walk is far below its white noise: 20 min cannot show it.
    noise = NoiseModel(gyroscope_random_walk=1e-7)
    imu, _ = simulate_static(4, 1200.0, RATE_HZ, noise=noise)
    with pytest.raises(ObservabilityError, match=r"gyroscope random walk .* not resolved .* "
                                                 r"record at least [0-9.]+ h static") as exc:
        characterise_noise(imu)
    assert "\n" not in str(exc.value)
    d = characterise_noise(imu, require_random_walk=False).to_dict()
    assert d["gyroscope_random_walk"] is None and "gyroscope_random_walk" in d["unobservable"]
    assert d["accelerometer_random_walk"] is not None


def test_log_shorter_than_minutes_is_refused() -> None:
    imu, _ = simulate_static(5, 300.0, RATE_HZ)
    with pytest.raises(ObservabilityError, match="needs at least 10 min"):
        characterise_noise(imu)


def test_moving_log_is_refused() -> None:
    imu, _ = simulate_static(6, 1200.0, RATE_HZ)
    acc = imu.accel.copy()
    sel = (imu.t > 400) & (imu.t < 430)
    acc[sel] += np.random.default_rng(0).normal(0.0, 2.0, (sel.sum(), 3))  # handled
    with pytest.raises(ObservabilityError, match="not static: .* accel variance"):
        characterise_noise(ImuSamples(imu.t, imu.gyro, acc))
    gyr = imu.gyro.copy()
    gyr[sel, 2] += 0.5  # a turn about the vertical: only the gyro sees it
    with pytest.raises(ObservabilityError, match="not static: the gyro shows rotation"):
        characterise_noise(ImuSamples(imu.t, gyr, imu.accel))


def test_wrong_rate_is_an_input_error() -> None:
    imu, _ = simulate_static(7, 1200.0, RATE_HZ)
    with pytest.raises(InputError, match="timestamps give 20 Hz"):
        characterise_noise(imu, rate_hz=100.0)
    keep = np.random.default_rng(1).random(len(imu)) > 0.05  # drop 5 % of the samples
    with pytest.raises(InputError, match="uniform sampling"):
        characterise_noise(imu.select(keep))


def _same(a: object, b: object) -> None:
    """Dataclasses (or arrays) equal field by field, NaN equal to NaN."""
    import dataclasses

    if dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):  # type: ignore[arg-type]
            _same(getattr(a, f.name), getattr(b, f.name))
    elif isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b)
        assert np.asarray(b).dtype.kind == a.dtype.kind
    else:
        assert a == b


def test_noise_file_round_trip_and_kind() -> None:
    """to_dict / from_dict restore the same result (an unresolved random walk included), the
    file says what it is, and a newer version or another kind is refused."""
    import yaml

    from mocap_calib.core.intrinsics.noise_result import AllanResult
    from mocap_calib.core.versioned import KindError

    imu, _ = simulate_static(4, 1200.0, RATE_HZ, noise=NoiseModel(gyroscope_random_walk=1e-7))
    res = characterise_noise(imu, require_random_walk=False, aggregate="max")
    assert not np.all(res.gyroscope.random_walk_resolved)
    d = res.to_dict()
    assert list(d)[:2] == ["kind", "version"] and d["kind"] == "noise"
    # Through YAML text, as the file is written and read.
    back = AllanResult.from_dict(yaml.safe_load(yaml.safe_dump(d)))
    _same(res, back)
    with pytest.raises(KindError, match="newer mocap-calib"):
        AllanResult.from_dict({**d, "version": d["version"] + 1})
    with pytest.raises(KindError, match="intrinsics file, not a noise file"):
        AllanResult.from_dict({**d, "kind": "intrinsics"})
