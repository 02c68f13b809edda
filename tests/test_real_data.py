"""The real recordings in ../shared/data are the judge (they run in CI, which has them).

For each: the default calibration exits 0 with a plausible answer, or refuses; BROAD's optical
data were rotated into the IMU frame and synchronised by the dataset's authors, so R_MI is
within a degree of identity and the clock offset a few ms; EuRoC's segments agree within their
sigmas and its answer moves little under noise densities x3 and x1/3.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_data

from mocap_calib.core.model import so3
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.workflows.session import InputSpec, NoiseSpec, load_session

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

BROAD = ("broad_15_undisturbed_fast_translation_A", "broad_21_undisturbed_fast_combined",
         "broad_27_disturbed_phone_vibration_B")


def _calibrate(spec: InputSpec, factor: float = 1.0, verdict: bool = True):
    """Default options; ``factor`` scales the IMU noise densities and random walks (without
    ``verdict`` the segments and sensitivity refits are skipped: the values do not depend on
    them)."""
    session = load_session(spec)
    opts = CalibrationOptions(noise=NoiseSpec().resolve(session.sensor_noise).imu_scaled(factor))
    if not verdict:
        opts = replace(opts, segments=0, sensitivity=False)
    return calibrate(session.imu, session.mocap, opts)


@pytest.fixture(scope="module")
def broad() -> dict:
    out = {}
    for trial in BROAD:
        csv: Path = shared_data(trial, "data.csv")
        out[trial] = _calibrate(InputSpec(imu=csv, mocap=csv, columns="broad"))
    return out


@pytest.mark.parametrize("trial", BROAD)
def test_broad_trial_calibrates_plausibly_without_a_given_clock(broad, trial: str) -> None:
    r = broad[trial]
    assert r.plausibility.verdict == "plausible", r.plausibility
    # Measured 0.60, 0.19, 0.18 deg from identity.
    assert np.degrees(np.linalg.norm(so3.log(r.R_marker_imu))) < 1.0
    # The authors synchronised the streams to a few ms: measured -3.3, -3.8, -4.0 ms
    # (trials 15, 21, 27); a search that returned 0 would fail.
    assert r.time_offset == pytest.approx(-0.004, abs=0.001)
    assert r.clock.margin_z >= 3.0
    # The segments were compared on every parameter, and where they disagree beyond 3
    # combined sigmas the sigmas grew to cover it (never a failed check with the sigmas it
    # contradicted).
    z = r.consistency.max_pairwise_z
    assert {p.symbol for p in z} == {"R_MI", "p_MI", "t_d"}, z
    for p, v in z.items():
        assert np.isfinite(v) and v > 0.0, z
        if v > 3.0:
            terms = r.estimate(p).terms
            assert terms.consistency_factor >= v / 3.0 - 1e-3, terms


def _pair_z(a, b) -> dict[str, float]:
    rot = so3.log(a.R_marker_imu.T @ b.R_marker_imu)
    return {"R_MI": float(np.max(np.abs(rot) / np.hypot(a.sigma_rotation, b.sigma_rotation))),
            "p_MI": float(np.max(np.abs(a.translation - b.translation)
                                 / np.hypot(a.sigma_translation, b.sigma_translation)))}


def test_broad_trials_of_one_rig_roughly_agree(broad) -> None:
    """One IMU and rigid body, three recordings, each aligned by the dataset's authors.
    Measured pairwise: R_MI 2.1-8.4, p_MI 2.1-6.4 combined sigmas (8.4: trials 15 and 27,
    7.7 while chance moves under the other IMU densities still padded the sigmas; without the
    mocap level estimated from the data and the effects-shown term in the sigmas: up to 10.3).
    Bound at 9 so that sigmas that leave either out fail."""
    for a, b in ((0, 1), (0, 2), (1, 2)):
        z = _pair_z(broad[BROAD[a]], broad[BROAD[b]])
        assert max(z.values()) < 9.0, (BROAD[a], BROAD[b], z)


@pytest.mark.xfail(strict=True, reason="the trials do not agree within 3 combined sigmas: "
                   "each file's optical data were aligned to its IMU by the dataset's authors "
                   "(pairs up to 8.4 combined sigmas in R_MI, 6.4 in p_MI)")
def test_broad_trials_agree_within_three_sigmas(broad) -> None:
    for a, b in ((0, 1), (0, 2), (1, 2)):
        z = _pair_z(broad[BROAD[a]], broad[BROAD[b]])
        assert max(z.values()) <= 3.0, (BROAD[a], BROAD[b], z)


#: mocap2gt (github.com/zichao-shu/mocap2gt, commit 797f302, built from source with Ceres 2.1)
#: on EuRoC V2_03 with its shipped estimator_config.yaml, relin_iter_count 5 (converged): p_MI
#: (mm, marker frame) of the whole session and of its three time-thirds.
MOCAP2GT_P_MI_MM = np.array([90.01, -25.37, -110.15])
#: Its shipped IMU noise: accel white, accel walk, gyro white, gyro walk (Kalibr units).
MOCAP2GT_IMU_NOISE = {"accelerometer_noise_density": 2.0688e-2,
                      "accelerometer_random_walk": 1.0356e-3,
                      "gyroscope_noise_density": 8.3882e-4, "gyroscope_random_walk": 1.1771e-5}


def _gt_implied(mav0: Path) -> dict:
    """T_MI implied by the dataset's own ground truth (scripts/euroc_reference.py: its IMU poses
    against its Vicon poses; no calibration code involved)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    from euroc_reference import gt_implied

    return gt_implied(mav0)


@pytest.fixture(scope="module")
def euroc() -> tuple[InputSpec, object, dict]:
    mav0 = shared_data("euroc_V2_03_difficult", "mav0")
    spec = InputSpec(mav0=(mav0,))
    return spec, _calibrate(spec), _gt_implied(mav0)


def test_euroc_lands_near_what_its_ground_truth_implies(euroc) -> None:
    _, r, ref = euroc
    assert r.plausibility.verdict == "plausible", r.plausibility
    assert r.time_offset == pytest.approx(-0.200, abs=0.002)  # the 200 ms the clocks differ
    rot = so3.log(ref["R_MI"].T @ r.R_marker_imu)
    dp = r.translation - ref["p_MI"]
    # Measured: 0.33 deg and (2.1, -4.1, -0.4) mm away, sigmas (1.0, 1.3, 3.3) mm. The
    # reference is itself an estimate (the dataset's own estimator's IMU poses against its
    # Vicon poses): mocap2gt, an independent estimator, lands (1.8, -5.0, 0.4) mm from it and
    # 1.2 mm from us, so along y the reference is off by more than our sigma. Asked: each
    # axis within 3 of our sigmas of the peer's answer, and the whole within 0.4 deg / 5 mm of
    # the reference (an answer as far as the old 8.6 mm fails).
    assert np.all(np.abs(r.translation - MOCAP2GT_P_MI_MM / 1e3) <= 3.0 * r.sigma_translation), (
        1e3 * r.translation, r.sigma_translation)
    assert np.degrees(np.linalg.norm(rot)) < 0.4
    assert np.linalg.norm(dp) < 0.005


@pytest.mark.xfail(strict=True, reason="not within 0.3 deg and 3 mm: measured 0.33 deg and "
                   "4.6 mm from the ground-truth-implied T_MI (mocap2gt: 0.28 deg / 5.3 mm "
                   "shipped; we land 1.2 mm from its converged answer)")
def test_euroc_within_a_third_of_a_degree_and_3_mm_of_its_ground_truth(euroc) -> None:
    _, r, ref = euroc
    assert np.degrees(np.linalg.norm(so3.log(ref["R_MI"].T @ r.R_marker_imu))) <= 0.3
    assert np.linalg.norm(r.translation - ref["p_MI"]) <= 0.003


def test_euroc_segments_agree_and_noise_densities_barely_matter(euroc) -> None:
    spec, r, _ = euroc
    for p, z in r.consistency.max_pairwise_z.items():
        assert z <= 3.0, f"segments disagree on {p.symbol}: {z:.2f} combined sigmas"
    # Under noise densities x3 and x1/3 and the correlated mocap model the answer moves by
    # about its reported sigma at most. The sigmas carry only moves beyond chance (the x3
    # estimator scatters more than ours): measured p_MI 1.46 at x3, within 2 chance sigmas,
    # R_MI 1.005 ...
    for factor, moved in r.sensitivity.moved.items():
        for p, z in moved.items():
            assert z <= 1.5, f"noise {factor}: {p.symbol} moves {z:.2f} sigmas"
    # ... and so does a user's own rerun given those densities, from scratch (a refit that
    # kept the robust weights and the mocap noise model once said <= 1 while reruns moved
    # 1.16 sigma).
    for factor in (3.0, 1.0 / 3.0):
        o = _calibrate(spec, factor, verdict=False)
        moved = {"R_MI": np.abs(so3.log(r.R_marker_imu.T @ o.R_marker_imu)) / r.sigma_rotation,
                 "p_MI": np.abs(o.translation - r.translation) / r.sigma_translation,
                 "t_d": np.abs([o.time_offset - r.time_offset]) / r.sigma_time_offset}
        # Measured 1.0 (p_MI at x1/3; the in-run refit says 1.0): a rerun also re-runs the
        # clock search, stages 1-2 and the robust weights from scratch, so it lands a little
        # further than the refit the sigma covers.
        for name, z in moved.items():
            assert np.max(z) < 1.25, f"rerun x{factor:.3g}: {name} moves {np.max(z):.2f} sigmas"
    # ... with sigmas that are not padded past use: independent thirds of the session differ
    # by up to 0.30 deg and 3.5 mm (scripts/real_data_study.py), so sigmas much larger than
    # these would be padding.
    assert np.max(r.sigma_rotation) < np.radians(0.3)
    assert np.max(r.sigma_translation) < 0.010


def test_euroc_on_the_peers_noise_model_lands_where_the_peer_does(euroc) -> None:
    """Two estimators on one noise model should agree. Before the lever arm turned with the
    filter's attitude (not the measured one), ours landed 40 mm from mocap2gt here; now 1.6
    mm (p_MI's sigmas: 5-45 mm; 1.4 mm with the clock column from the raw samples, whose
    rotor vibration moves t_d by 0.4 ms here), and the thirds agree as closely as the peer's
    (3.2 mm / 0.30 deg; mocap2gt 3.15 mm / 0.305 deg)."""
    spec, _, _ = euroc
    session = load_session(spec)
    noise = replace(NoiseSpec().resolve(session.sensor_noise), **MOCAP2GT_IMU_NOISE)
    opts = CalibrationOptions(noise=noise, segments=0, sensitivity=False, effect_tests=False)
    r = calibrate(session.imu, session.mocap, opts)
    assert np.linalg.norm(1e3 * r.translation - MOCAP2GT_P_MI_MM) < 2.0, 1e3 * r.translation
    from mocap_calib.core.prepare.crop import crop_session

    dur = session.imu.duration
    parts = [calibrate(*crop_session(session.imu, session.mocap, k * dur / 3, (k + 1) * dur / 3,
                                     None), opts) for k in range(3)]
    spread = max(np.linalg.norm(a.translation - b.translation)
                 for a, b in ((parts[0], parts[1]), (parts[0], parts[2]), (parts[1], parts[2])))
    assert spread < 0.004, 1e3 * spread
