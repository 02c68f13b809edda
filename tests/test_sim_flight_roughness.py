"""A real flight's roughness in the simulator: rotor vibration seen through the IMU's sampling
(aliased lines where sampling theory puts them), white noise above the data sheet (the
high-frequency floor), the effective density the truth file reports against the spectrum, the
``flying`` preset, and seeds: a knob switched on leaves every other draw as it was."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import welch

from mocap_calib.core.model.types import NoiseModel
from mocap_calib.errors import InputError
from mocap_calib.sim.flight import SimConfig, simulate_flight
from mocap_calib.sim.presets import preset_config
from mocap_calib.sim.vibration import Vibration
from mocap_calib.workflows.simulate import simulate_to_folder

#: No white noise, no mocap noise: the difference of two flights is the vibration alone.
QUIET = NoiseModel(gyroscope_noise_density=1e-13, accelerometer_noise_density=1e-13,
                   mocap_position_sigma=1e-13, mocap_rotation_sigma=1e-13)


def folded(f: float, rate: float) -> float:
    """Sampling theory: a tone at ``f`` sampled at ``rate`` shows at the distance from ``f`` to
    the nearest multiple of ``rate``."""
    k = np.floor(f / rate + 0.5)
    return abs(f - k * rate)


def vibration_only(cfg: SimConfig, vib: Vibration) -> tuple[np.ndarray, np.ndarray]:
    """(accel, gyro) of the flight with ``vib`` minus the same flight without it."""
    a = simulate_flight(cfg)
    b = simulate_flight(replace(cfg, vibration=vib))
    return b.imu.accel - a.imu.accel, b.imu.gyro - a.imu.gyro


def peaks(x: np.ndarray, rate: float, n: int, nperseg: int = 4096
          ) -> tuple[list[float], np.ndarray, np.ndarray]:
    """The ``n`` strongest spectral peaks (Hz) of ``x`` (summed over axes), at least 3 Hz
    apart, and the spectrum."""
    f, p = welch(x, fs=rate, nperseg=nperseg, axis=0)
    p = p.sum(axis=1)
    found: list[float] = []
    for i in np.argsort(p)[::-1]:
        if all(abs(f[i] - g) > 3.0 for g in found):
            found.append(float(f[i]))
        if len(found) == n:
            break
    return found, f, p


@pytest.mark.parametrize("rotor_hz,imu_rate", [(131.0, 200.0), (97.0, 200.0), (131.0, 400.0),
                                               (131.0, 1000.0), (145.0, 200.0)])
def test_vibration_lines_alias_where_sampling_theory_puts_them(rotor_hz: float,
                                                               imu_rate: float) -> None:
    cfg = SimConfig(seed=2, duration=30.0, imu_rate=imu_rate, mocap_rate=100.0, noise=QUIET)
    vib = Vibration(accel_rms=2.0, gyro_rms=0.05, band_hz=(rotor_hz, rotor_hz))
    acc, gyr = vibration_only(cfg, vib)
    fundamental, harmonic = folded(rotor_hz, imu_rate), folded(2 * rotor_hz, imu_rate)
    for x in (acc, gyr):
        found, f, p = peaks(x, imu_rate, 2)
        resolution = f[1] - f[0]
        assert sorted(found) == pytest.approx(sorted([fundamental, harmonic]),
                                              abs=2 * resolution)
    if imu_rate == 200.0 and rotor_hz == 145.0:
        assert fundamental == 55.0  # the example of the module's documentation


@pytest.mark.parametrize("imu_rate", [200.0, 1000.0])
def test_the_harmonic_has_a_quarter_of_the_fundamentals_power(imu_rate: float) -> None:
    """Rotors apart (110-116 Hz, so that their lines add in power): the harmonic, at half the
    fundamental's amplitude, carries a quarter of its power, wherever both fold (at 200 Hz
    to 84-90 and 20-32 Hz)."""
    cfg = SimConfig(seed=2, duration=60.0, imu_rate=imu_rate, noise=QUIET)
    acc, gyr = vibration_only(cfg, Vibration(accel_rms=2.0, gyro_rms=0.05,
                                             band_hz=(110.0, 116.0)))
    for x in (acc, gyr):
        f, p = welch(x, fs=imu_rate, nperseg=8192, axis=0)
        p = p.sum(axis=1)
        fundamental = float(p[np.abs(f - folded(113.0, imu_rate)) <= 4.0].sum())
        harmonic = float(p[np.abs(f - folded(226.0, imu_rate)) <= 7.0].sum())
        # Beats between rotors move the ratio by up to 20 % over 60 s.
        assert harmonic / fundamental == pytest.approx(0.25, rel=0.25)
        assert fundamental + harmonic > 0.97 * p.sum()


def test_wandering_rotors_stay_in_their_band_and_fold_into_its_alias() -> None:
    cfg = SimConfig(seed=4, duration=60.0, noise=QUIET)
    vib = Vibration(accel_rms=2.0, harmonic=0.0, band_hz=(95.0, 145.0))
    acc, _ = vibration_only(cfg, vib)
    # 95-145 Hz sampled at 200 Hz shows at 55-100 Hz (95-100 stay, 100-145 fold to 100-55).
    f, p = welch(acc, fs=200.0, nperseg=2048, axis=0)
    p = p.sum(axis=1)
    inside = (f >= 55.0 - 1.0) & (f <= 100.0)
    assert p[~inside].sum() < 0.01 * p.sum()
    # The speeds wander over most of the band (the alias band is filled, not one line).
    occupied = f[inside][p[inside] > 0.01 * p[inside].max()]
    assert occupied.max() - occupied.min() > 25.0
    truth = simulate_flight(replace(cfg, vibration=vib)).truth["simulation"]["in_flight"]
    for lo, hi in truth["vibration"]["rotor_speed_range_hz"]:
        assert 95.0 <= lo < hi <= 145.0 and hi - lo > 10.0


def test_vibration_levels_and_direction() -> None:
    cfg = SimConfig(seed=6, duration=60.0, noise=QUIET)
    shares = []
    for seed in (6, 7, 8):
        acc, gyr = vibration_only(replace(cfg, seed=seed),
                                  Vibration(accel_rms=2.0, gyro_rms=0.04))
        assert np.sqrt(np.mean(np.sum(acc**2, axis=1))) == pytest.approx(2.0, rel=0.1)
        assert np.sqrt(np.mean(np.sum(gyr**2, axis=1))) == pytest.approx(0.04, rel=0.1)
        var = acc.var(axis=0)
        assert np.all(var > 0.01 * var.sum())  # present on every axis
        shares.append(var[2] / var.sum())
    assert np.mean(shares) > 0.6  # mostly along the thrust axis (z of the IMU frame)


def test_anti_alias_filter_scales_each_line_by_its_response() -> None:
    cfg = SimConfig(seed=3, duration=30.0, noise=QUIET, imu_rate=1000.0)
    band = (131.0, 131.0)
    raw, _ = vibration_only(cfg, Vibration(accel_rms=2.0, band_hz=band))
    lp, _ = vibration_only(cfg, Vibration(accel_rms=2.0, band_hz=band, anti_alias_hz=50.0))
    f, p_raw = welch(raw, fs=1000.0, nperseg=4096, axis=0)
    _, p_lp = welch(lp, fs=1000.0, nperseg=4096, axis=0)
    for line in (131.0, 262.0):
        near = np.abs(f - line) < 1.0
        gain2 = 1.0 / (1.0 + (line / 50.0) ** 2)  # first-order low-pass, power response
        assert p_lp[near].sum() / p_raw[near].sum() == pytest.approx(gain2, rel=0.05)


def test_white_noise_factor_shows_in_the_high_frequency_floor() -> None:
    """Above the flight's motion (< 2 Hz) the accelerometer's spectrum is its white noise:
    one-sided PSD 2 q^2 with q the density simulated; the truth file reports that q."""
    sheet = NoiseModel()
    for factor in (1.0, 10.0):
        sim = simulate_flight(SimConfig(seed=5, duration=120.0, accel_noise_factor=factor,
                                        gyro_noise_factor=3.0))
        f, p = welch(sim.imu.accel, fs=200.0, nperseg=1024, axis=0)
        floor = np.sqrt(np.median(p[(f > 30.0) & (f < 95.0)], axis=0) / 2.0)
        want = factor * sheet.accelerometer_noise_density
        np.testing.assert_allclose(floor, want, rtol=0.1)
        assert sim.truth["noise"]["accelerometer_noise_density"] == pytest.approx(want)
        f, p = welch(sim.imu.gyro, fs=200.0, nperseg=1024, axis=0)
        gfloor = np.sqrt(np.median(p[(f > 30.0) & (f < 95.0)], axis=0) / 2.0)
        np.testing.assert_allclose(gfloor, 3.0 * sheet.gyroscope_noise_density, rtol=0.1)


def test_effective_density_agrees_with_the_sampled_spectrum() -> None:
    """The truth's effective density is the vibration's mean power in 0-5 Hz as a white
    density: measured here from the spectrum of the simulated samples."""
    cfg = SimConfig(seed=9, duration=240.0, noise=QUIET)
    vib = Vibration(accel_rms=2.0, gyro_rms=0.03, band_hz=(95.0, 125.0))
    acc, _ = vibration_only(cfg, vib)
    truth = simulate_flight(replace(cfg, vibration=vib)).truth["simulation"]["in_flight"]
    reported = np.asarray(truth["vibration"]["effective_density_accel"])
    f, p = welch(acc, fs=200.0, nperseg=4096, axis=0)
    low = (f > 0.0) & (f <= 5.0)
    measured = np.sqrt(p[low].mean(axis=0) / 2.0)
    assert reported.max() > 0.01  # the harmonic of 95-100 Hz folds into 0-10 Hz
    np.testing.assert_allclose(measured, reported, rtol=0.15)
    total = np.asarray(truth["total_density_accel"])
    np.testing.assert_allclose(total, np.hypot(1e-13, reported), rtol=1e-9)


def test_a_knob_switched_on_leaves_every_other_draw() -> None:
    cfg = SimConfig(seed=11, duration=10.0, effects={"time_offset": None, "mocap_dropouts": [2],
                                                     "imu_dropouts": [3]})
    base = simulate_flight(cfg)
    rough = simulate_flight(replace(cfg, vibration=Vibration(accel_rms=2.0, gyro_rms=0.03),
                                    accel_noise_factor=10.0))
    np.testing.assert_array_equal(base.mocap.position, rough.mocap.position)
    np.testing.assert_array_equal(base.imu.t, rough.imu.t)
    np.testing.assert_array_equal(base.accel_bias_true, rough.accel_bias_true)
    np.testing.assert_array_equal(base.imu.gyro != rough.imu.gyro, True)
    for key in ("T_marker_imu", "gyro_bias", "accel_bias", "effects", "time_offset"):
        assert base.truth[key] == rough.truth[key]
    # Off is the default: an explicit "off" gives the default flight, bit for bit.
    off = simulate_flight(replace(cfg, vibration=Vibration(), accel_noise_factor=1.0))
    np.testing.assert_array_equal(base.imu.accel, off.imu.accel)
    assert base.truth == off.truth and "in_flight" not in base.truth["simulation"]
    assert preset_config("none", seed=11, duration=10.0, effects=cfg.effects) == cfg


def test_flying_preset_is_the_documented_regime() -> None:
    cfg = preset_config("flying", seed=3, duration=60.0)
    sheet = NoiseModel()
    assert (cfg.imu_rate, cfg.mocap_rate, cfg.mocap_noise_corr) == (200.0, 100.0, 0.3)
    assert cfg.accel_noise_factor == 10.0 and cfg.gyro_noise_factor == 1.0
    assert cfg.vibration.accel_rms == 2.0 and cfg.vibration.band_hz == (95.0, 145.0)
    assert cfg.vibration.harmonic > 0 and cfg.vibration.gyro_rms > 0
    assert cfg.noise.mocap_position_sigma == 0.5e-3
    assert np.degrees(cfg.noise.mocap_rotation_sigma) == pytest.approx(0.2)
    for k in ("gyroscope_noise_density", "accelerometer_noise_density",
              "gyroscope_random_walk", "accelerometer_random_walk"):
        assert getattr(cfg.noise, k) == getattr(sheet, k)  # the data sheet's, bias walks on
    assert 0.002 <= cfg.effects["time_offset"][0] <= 0.01
    # Given values override the preset's; effects merge.
    more = preset_config("flying", {"accel_rms": 3.0}, seed=3, duration=60.0,
                         effects={"time_offset": [0.002], "clock_drift": None})
    assert more.vibration.accel_rms == 3.0 and more.vibration.gyro_rms == cfg.vibration.gyro_rms
    assert more.effects == {"time_offset": [0.002], "clock_drift": None}
    with pytest.raises(InputError, match="preset"):
        preset_config("bumpy")


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_flying_preset_same_seed_same_bytes(tmp_path: Path) -> None:
    for name in ("a", "b"):
        simulate_to_folder(tmp_path / name, seed=4, duration=8.0, preset="flying")
    simulate_to_folder(tmp_path / "c", seed=5, duration=8.0, preset="flying")
    simulate_to_folder(tmp_path / "d", seed=4, duration=8.0, preset="flying", vibration=3.0)
    a, b, c, d = (_files(tmp_path / n) for n in "abcd")
    assert a == b
    assert a["mav0/imu0/data.csv"] != c["mav0/imu0/data.csv"]
    assert a["mav0/imu0/data.csv"] != d["mav0/imu0/data.csv"]
    assert a["mav0/vicon0/data.csv"] == d["mav0/vicon0/data.csv"]
    assert b"preset: flying" in a["truth.yaml"] and b"accel_rms: 3.0" in d["truth.yaml"]


@pytest.mark.parametrize("vib,must", [
    (Vibration(accel_rms=-1.0), "accel RMS"),
    (Vibration(accel_rms=1.0, band_hz=(150.0, 100.0)), "rotor band"),
    (Vibration(accel_rms=1.0, harmonic=2.0), "harmonic"),
    (Vibration(accel_rms=1.0, anti_alias_hz=0.5), "anti-alias"),
])
def test_bad_vibration_is_refused_in_one_line(vib: Vibration, must: str) -> None:
    with pytest.raises(InputError, match=must) as err:
        simulate_flight(SimConfig(duration=5.0, vibration=vib))
    assert "\n" not in str(err.value)
    with pytest.raises(InputError, match="noise-factor"):
        simulate_flight(SimConfig(duration=5.0, accel_noise_factor=0.0))
