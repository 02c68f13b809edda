"""Multi-position calibration of raw counts, units-free quality figures, imu_tk's threshold and
files, and the gyro's g-sensitivity, against the simulator's truth."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from mocap_calib.core.intrinsics.multipos import MultiposResult, calibrate_multipos
from mocap_calib.core.intrinsics.multipos.detector import detect_static_intervals
from mocap_calib.core.intrinsics.multipos.units import RawConversion
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.errors import InputError
from mocap_calib.sim.multipos import G_STD, CountsSpec, simulate_multipos

SIGNED = CountsSpec()
UNSIGNED = CountsSpec(accel_offset=32768.0, gyro_offset=32768.0, lo=0.0, hi=65535.0)


def nominal(spec: CountsSpec) -> RawConversion:
    """The simulated part's datasheet conversion (what the truth's SI values are for)."""
    return RawConversion(spec.accel_scale, spec.accel_offset, spec.gyro_scale,
                         spec.gyro_offset, "given")


@cache
def session(seed: int, counts: CountsSpec | None = SIGNED, g: float | None = None
            ) -> tuple[ImuSamples, dict]:
    return simulate_multipos(seed, counts=counts, g_sensitivity=g)


@cache
def raw_result(seed: int, counts: CountsSpec = SIGNED, g: float | None = None
               ) -> MultiposResult:
    return calibrate_multipos(session(seed, counts, g)[0], raw=True)


def errors(res: MultiposResult, truth: dict) -> dict[str, float]:
    """Worst scale (relative), misalignment (deg) and bias errors against the truth, in the
    truth's units."""
    out = {}
    off = ~np.eye(3, dtype=bool)
    for sensor in ("accel", "gyro"):
        M = getattr(res, f"{sensor}_matrix")
        T = np.asarray(truth[f"{sensor}_matrix"])
        out[f"{sensor}_scale"] = float(np.max(np.abs(np.diag(M) / np.diag(T) - 1.0)))
        out[f"{sensor}_misalignment_deg"] = float(np.degrees(np.max(np.abs(
            (M - T) / np.diag(T)[:, None])[off])))
        out[f"{sensor}_bias"] = float(np.max(np.abs(getattr(res, f"{sensor}_bias")
                                                    - np.asarray(truth[f"{sensor}_bias"]))))
    return out


def assert_targets(e: dict[str, float]) -> None:
    """Issue 6's targets."""
    assert e["accel_scale"] < 1e-3 and e["gyro_scale"] < 1e-3, e
    assert e["accel_misalignment_deg"] < 0.05 and e["gyro_misalignment_deg"] < 0.05, e
    assert e["accel_bias"] < 5e-3, e
    assert e["gyro_bias"] < 1e-4, e


# --------------------------------------------------------------------------------------------
# Raw counts
# --------------------------------------------------------------------------------------------

@pytest.mark.slow  # full calibrations: in the whole suite, not the quick subset
@pytest.mark.parametrize("seed", [0, 1])
def test_raw_counts_meet_the_targets(seed: int) -> None:
    """16-bit counts, no units given: the starting point comes from the data; the result,
    taken to the part's datasheet units, meets the SI calibration's targets."""
    imu, truth = session(seed)
    assert np.all(imu.accel == np.round(imu.accel)) and np.max(np.abs(imu.accel)) > 1000
    res = raw_result(seed)
    assert res.raw_input is not None and res.raw_input.source == "fitted"
    e = errors(res.in_units(nominal(CountsSpec())), truth)
    print("raw counts errors:", e)
    assert_targets(e)
    assert res.poorly_determined == []
    # Without a nominal the SI form is imu_tk's T^-1: unit diagonal for the accelerometer.
    assert np.allclose(np.diag(res.accel_matrix), 1.0, atol=1e-12)


def test_unsigned_counts_with_an_offset() -> None:
    """Unsigned output (offset 32768, as imu_tk's example): the ellipsoid start finds it."""
    imu, truth = session(2, UNSIGNED)
    assert imu.accel.min() >= 0
    res = calibrate_multipos(imu, raw=True)
    assert_targets(errors(res.in_units(nominal(UNSIGNED)), truth))


@pytest.mark.slow
def test_a_nominal_only_sets_the_starting_point() -> None:
    """The datasheet values, or ones 30 % / 2x off, give the same calibration as none."""
    imu, truth = session(0)
    good = nominal(CountsSpec())
    auto = raw_result(0).in_units(good)
    for scale_a, scale_g in ((1.0, 1.0), (1.3, 0.5), (0.8, 2.0)):
        given = RawConversion(good.accel_scale * scale_a, 0.0, good.gyro_scale * scale_g, 0.0)
        res = calibrate_multipos(imu, raw=True, nominal=given)
        assert res.raw_input is given
        same = res.in_units(good)
        for name in ("accel_matrix", "gyro_matrix", "accel_bias", "gyro_bias"):
            assert np.allclose(getattr(same, name), getattr(auto, name), rtol=0, atol=1e-7), name
        assert same.gyro_chi2 == pytest.approx(auto.gyro_chi2, rel=1e-5)
        assert same.poorly_determined == auto.poorly_determined == []


@pytest.mark.slow  # full calibrations: in the whole suite, not the quick subset
@pytest.mark.parametrize("factor", [10.0, 0.1])
def test_rescaled_input_gives_identical_figures(factor: float) -> None:
    """Counts of a part 10x more (or less) sensitive: the same calibrated figures (noise and
    residuals in calibrated units, relative sigmas), the scales 1/10 (10x)."""
    imu, _ = session(1)
    ref = raw_result(1)
    scaled = ImuSamples(imu.t, imu.gyro * factor, imu.accel * factor, imu.time_origin_ns)
    res = calibrate_multipos(scaled, raw=True)
    for name in ("accel_chi2", "gyro_chi2", "accel_residual_rms", "gyro_residual_rms",
                 "threshold_multiple", "accel_condition", "gyro_condition"):
        assert getattr(res, name) == pytest.approx(getattr(ref, name), rel=1e-6), name
    assert res.poorly_determined == ref.poorly_determined
    assert [e["n_intervals"] for e in res.threshold_scan] == [
        e["n_intervals"] for e in ref.threshold_scan]
    # The SI results (sigmas included) are the same; imu_tk's K carries the factor.
    for name in ("accel_matrix", "gyro_matrix", "accel_bias", "gyro_bias",
                 "accel_matrix_sigma", "gyro_matrix_sigma", "gyro_bias_sigma"):
        assert np.allclose(getattr(res, name), getattr(ref, name), rtol=1e-6,
                           atol=1e-12), name
    assert res.raw_input is not None and ref.raw_input is not None
    assert np.allclose(res.raw_input.gyro_scale * factor, ref.raw_input.gyro_scale, rtol=1e-7)


@pytest.mark.slow
def test_quality_figures_do_not_depend_on_the_gyro_nominal_scale() -> None:
    """The gyro chi2 does not move with the nominal scale used for the counts (a 4x change
    would)."""
    imu, _ = session(0)
    good = nominal(CountsSpec())
    chi2 = []
    for f in (0.5, 1.0, 2.0):
        res = calibrate_multipos(imu, raw=True, nominal=RawConversion(
            good.accel_scale, 0.0, good.gyro_scale * f, 0.0))
        chi2.append((res.gyro_chi2, res.accel_chi2, tuple(res.poorly_determined)))
    assert all(c[2] == () for c in chi2)
    assert np.allclose([c[0] for c in chi2], chi2[1][0], rtol=1e-5)
    assert np.allclose([c[1] for c in chi2], chi2[1][1], rtol=1e-5)


def test_options_that_need_raw_counts() -> None:
    imu, _ = session(0, None)
    with pytest.raises(InputError, match="raw counts only"):
        calibrate_multipos(imu, nominal=nominal(CountsSpec()))
    with pytest.raises(InputError, match="auto, on or off"):
        calibrate_multipos(imu, g_sensitivity="maybe")


# --------------------------------------------------------------------------------------------
# Static detector: imu_tk's threshold meaning
# --------------------------------------------------------------------------------------------

def test_threshold_is_a_multiple_of_the_variance_norm() -> None:
    """A stretch whose noise has twice the standard deviation of the initial rest has 4x its
    variance norm: static for k = 5, not for k = 3 (imu_tk's meaning; the squared norm's
    ratio, 16, would make it moving for both)."""
    rng = np.random.default_rng(1)
    rate, sd = 100.0, 0.02
    n0, n1, n2 = 4000, 1000, 1000  # 40 s rest, 10 s at 2x noise, 10 s rest
    sig = np.concatenate([np.full(n0, sd), np.full(n1, 2 * sd), np.full(n2, sd)])
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 1.0, (len(sig), 3)) * sig[:, None]
    imu = ImuSamples(np.arange(len(sig)) / rate, rng.normal(0.0, 1e-3, accel.shape), accel)
    noisy = slice(n0 + 100, n0 + n1 - 100)  # away from the window's edges
    for k, static in ((3.0, False), (5.0, True)):
        iv = detect_static_intervals(imu, k, init_static_s=35.0)
        mask = np.zeros(len(sig), bool)
        for a, b in iv:
            mask[a:b + 1] = True
        assert np.mean(mask[noisy]) == (1.0 if static else 0.0), k


# --------------------------------------------------------------------------------------------
# g-sensitivity
# --------------------------------------------------------------------------------------------

@pytest.mark.slow  # full calibrations: in the whole suite, not the quick subset
def test_g_sensitivity_is_recovered_and_needed() -> None:
    """A hidden G: recovered within 5 % of its norm, the gyro-integration residual with G at
    the noise level (that of the same session without G), several times larger without."""
    imu_g, truth = session(0, None, G_STD)
    imu_0, _ = session(0, None)  # the same session (same noise), G f left out
    G = np.asarray(truth["g_sensitivity"])
    res = calibrate_multipos(imu_g)
    t = res.g_sensitivity_test
    assert res.g_sensitivity is not None and t is not None and t["kept"] and t["significant"]
    err = float(np.linalg.norm(res.g_sensitivity - G) / np.linalg.norm(G))
    print(f"G error {100 * err:.2f} % of |G|; gyro residual with G "
          f"{np.degrees(t['gyro_rms_rad_with_g']):.4f} deg, without "
          f"{np.degrees(t['gyro_rms_rad_without_g']):.4f} deg")
    assert err < 0.05
    assert np.all(np.abs(res.g_sensitivity - G) < 4 * res.g_sensitivity_sigma)
    noise_level = calibrate_multipos(imu_0, g_sensitivity="off")
    assert res.gyro_residual_rms == t["gyro_rms_rad_with_g"]
    assert res.gyro_residual_rms < 1.3 * noise_level.gyro_residual_rms
    assert res.gyro_chi2 < 1.3 * max(noise_level.gyro_chi2, 1.0)
    assert t["gyro_rms_rad_without_g"] > 5.0 * t["gyro_rms_rad_with_g"]
    # Left out of the model, G spoils the calibration itself: the gyro fit cannot absorb it.
    off = calibrate_multipos(imu_g, g_sensitivity="off")
    assert off.gyro_residual_rms == pytest.approx(t["gyro_rms_rad_without_g"])
    assert_targets(errors(res, truth))


@pytest.mark.parametrize("seed", range(5))
def test_g_sensitivity_is_left_out_when_absent(seed: int) -> None:
    res = calibrate_multipos(session(seed, None)[0])
    t = res.g_sensitivity_test
    assert t is not None and not t["significant"] and not t["kept"], t
    assert res.g_sensitivity is None and "g_sensitivity" not in res.to_dict()


def test_g_sensitivity_from_raw_counts() -> None:
    imu, truth = session(1, CountsSpec(), G_STD)
    res = calibrate_multipos(imu, raw=True).in_units(nominal(CountsSpec()))
    G = np.asarray(truth["g_sensitivity"])
    assert res.g_sensitivity is not None
    assert np.linalg.norm(res.g_sensitivity - G) < 0.05 * np.linalg.norm(G)
    assert_targets(errors(res, truth))


# --------------------------------------------------------------------------------------------
# Result file and imu_tk's form
# --------------------------------------------------------------------------------------------

def test_raw_result_round_trip() -> None:
    import dataclasses

    import yaml

    res = calibrate_multipos(session(1, CountsSpec(), G_STD)[0], raw=True)
    back = MultiposResult.from_dict(yaml.safe_load(yaml.safe_dump(res.to_dict())))
    for f in dataclasses.fields(res):
        a, b = getattr(res, f.name), getattr(back, f.name)
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
        elif isinstance(a, RawConversion):
            assert a.to_dict() == b.to_dict()
        else:
            assert a == b, f.name


def test_imu_tk_form_calibrates_the_counts(tmp_path) -> None:
    """imu_tk's files: read back as CalibratedTriad_::load does, T K (raw - b) of the static
    counts is the true specific force (from the truth and the datasheet conversion)."""
    from mocap_calib.export.imu_tk import read_calib, write_imu_tk

    imu, truth = session(0)
    res = raw_result(0)
    acc, gyr = write_imu_tk(tmp_path / "imu", res)
    assert acc.name == "imu_acc.calib" and gyr.name == "imu_gyro.calib"
    blocks = acc.read_text().split("\n\n")
    assert [len(b.splitlines()) for b in blocks[:3]] == [3, 3, 3] and blocks[3] == ""
    T, K, b = read_calib(acc)
    assert np.allclose(np.diag(T), 1.0) and np.allclose(K, np.diag(np.diag(K)))
    iv = np.asarray(truth["simulation"]["static_intervals_s"])
    raw = np.array([imu.accel[(imu.t > a + 0.5) & (imu.t < z - 0.5)].mean(axis=0)
                    for a, z in iv])
    f_tk = (raw - b) @ (T @ K).T
    conv = nominal(CountsSpec())
    f_true = (conv.accel_scale * (raw - conv.accel_offset) - np.asarray(truth["accel_bias"])) \
        @ np.linalg.inv(np.asarray(truth["accel_matrix"])).T
    assert np.max(np.linalg.norm(f_tk - f_true, axis=1)) < 0.01  # m/s^2 (|g| 9.81)
    assert np.allclose(np.linalg.norm(f_tk, axis=1), 9.81, atol=0.01)
    T_g, K_g, b_g = read_calib(gyr)
    tk = res.imu_tk()["gyro"]
    assert np.allclose(T_g, tk["T"], rtol=1e-15) and np.allclose(b_g, tk["b"], rtol=1e-15)
