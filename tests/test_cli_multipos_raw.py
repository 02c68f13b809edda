"""``multipos --raw``, imu_tk's two-file input and ``export --to imu_tk``, end to end through the
CLI on simulated 16-bit counts."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from mocap_calib.core.intrinsics.multipos.result import MultiposResult
from mocap_calib.core.intrinsics.multipos.units import RawConversion
from mocap_calib.export.imu_tk import read_calib
from mocap_calib.io.formats.euroc import read_euroc_imu
from tests.test_cli_imu_tools import assert_error, cli, ok, run
from tests.test_multipos_raw import assert_targets, errors


def load(path: Path) -> dict[str, Any]:
    return yaml.safe_load(path.read_text())


def in_truth_units(path: Path, truth: dict[str, Any]) -> MultiposResult:
    """A written raw-count result in the simulated part's datasheet units (the truth's)."""
    c = truth["counts"]
    conv = RawConversion(c["accel_scale"], c["accel_offset"], c["gyro_scale"],
                         c["gyro_offset"])
    return MultiposResult.from_dict(load(path)).in_units(conv)


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("multipos_raw")


@pytest.fixture(scope="module")
def counts_session(work: Path) -> tuple[Path, dict[str, Any]]:
    """``simulate --protocol multipos --counts --effect gyro_g_sensitivity``."""
    out = work / "mpc"
    text = ok(cli(["simulate", out, "--protocol", "multipos", "--counts", "--effect",
                   "gyro_g_sensitivity", "--seed", 3]))
    assert "raw 16-bit counts" in text
    return out / "mav0" / "imu0" / "data.csv", load(out / "truth.yaml")


@pytest.fixture(scope="module")
def raw_run(work: Path, counts_session: tuple[Path, dict[str, Any]]) -> tuple[Path, str]:
    out = work / "raw.yaml"
    return out, ok(cli(["multipos", "--raw", "--imu", counts_session[0], "--out", out]))


def test_simulated_counts_look_like_a_16_bit_part(counts_session: tuple[Path, dict]) -> None:
    path, truth = counts_session
    imu = read_euroc_imu(path, raw=True)
    for x in (imu.gyro, imu.accel):
        assert np.all(x == np.round(x)) and np.all(np.abs(x) <= 32768)
    # |g| is 4096 counts at +-8 g.
    assert np.median(np.linalg.norm(imu.accel, axis=1)) == pytest.approx(4096, rel=0.02)
    assert "gyro_g_sensitivity" in truth["model"] and len(truth["g_sensitivity"]) == 3


def test_raw_counts_calibration(raw_run: tuple[Path, str],
                                counts_session: tuple[Path, dict[str, Any]]) -> None:
    path, out = raw_run
    truth = counts_session[1]
    d = load(path)
    assert d["kind"] == "intrinsics" and d["raw_input"]["source"] == "fitted"
    assert set(d["imu_tk"]["accel"]) == {"T", "K", "b"}
    res = in_truth_units(path, truth)
    e = errors(res, truth)
    print("CLI raw counts errors:", e)
    assert_targets(e)
    G = np.asarray(truth["g_sensitivity"])
    assert res.g_sensitivity is not None
    assert np.linalg.norm(res.g_sensitivity - G) < 0.05 * np.linalg.norm(G)
    test = d["diagnostics"]["g_sensitivity_test"]
    assert test["kept"] and test["gyro_rms_rad_without_g"] > 5 * test["gyro_rms_rad_with_g"]
    for text in ("accel scale K x", "m/s^2/count", "gyro offset b z", "gyro g-sensitivity zz",
                 "g-sensitivity G     kept", "imu_tk's meaning", "w_m = M_g w + G f + b_g",
                 "poorly determined   none"):
        assert text in out, text
    assert "accel scale error" not in out  # no nominal: scale errors mean nothing


def test_counts_without_raw_are_named_as_counts(counts_session: tuple[Path, dict],
                                                work: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Raw counts are not taken for deg/s."""
    imu = counts_session[0]
    for extra in ([], ["--gyro-unit", "deg/s"], ["--gyro-unit", "deg/s", "--accel-unit", "g"]):
        code, out, err = run(["multipos", "--imu", imu, "--out", work / "no.yaml", "-q",
                              *extra], capsys)
        assert_error((code, out, err), 2, "raw sensor counts.*multipos --raw")
        assert "pass --gyro-unit deg/s" not in err
    # A generic CSV of integer counts with a gyro slow enough to pass for deg/s.
    x = read_euroc_imu(imu, raw=True)
    csv = work / "counts.csv"
    np.savetxt(csv, np.column_stack([x.t, x.gyro, x.accel / 100]), delimiter=",",
               fmt=["%.6f"] + ["%d"] * 6)
    assert_error(run(["multipos", "--imu", csv, "--columns", "t=0,gyro=1:4,accel=4:7",
                      "--out", work / "no.yaml", "-q"], capsys), 2, "raw sensor counts")


def test_export_to_imu_tk(work: Path, raw_run: tuple[Path, str],
                          counts_session: tuple[Path, dict[str, Any]],
                          capsys: pytest.CaptureFixture[str]) -> None:
    path, _ = raw_run
    out = ok(run(["export", path, "--to", "imu_tk", "--out", work / "tk" / "imu"], capsys))
    assert "imu_acc.calib" in out and "G is not in imu_tk's format" in out
    d = load(path)
    for sensor, suffix in (("accel", "acc"), ("gyro", "gyro")):
        T, K, b = read_calib(work / "tk" / f"imu_{suffix}.calib")
        assert np.allclose(T, d["imu_tk"][sensor]["T"], rtol=1e-15)
        assert np.allclose(K, d["imu_tk"][sensor]["K"], rtol=1e-15)
        assert np.allclose(b, d["imu_tk"][sensor]["b"], rtol=1e-15)
    # K is the true sensitivity: the datasheet scale times the true scale (the truth is for
    # the datasheet's SI readings, a_m = M_a f + b_a with M_a = diag(s) (I + L)).
    truth = counts_session[1]
    T, K, _ = read_calib(work / "tk" / "imu_acc.calib")
    K_true = np.asarray(truth["counts"]["accel_scale"]) / np.diag(truth["accel_matrix"])
    assert np.allclose(np.diag(K), K_true, rtol=1e-3)
    bad = [(["export", path, "--to", "nonsense", "--out", work / "x"], 2,
            "--to.*'nonsense' is not one of .*imu_tk"),
           (["export", work / "missing.yaml", "--to", "imu_tk", "--out", work / "x"], 2,
            "not found")]
    for args, code, pattern in bad:
        assert_error(run(args, capsys), code, pattern)


def _triads(work: Path, imu_csv: Path, shifted: bool) -> tuple[Path, Path]:
    """imu_tk's two files ('t x y z', seconds) from a counts session; ``shifted``: the
    accelerometer on its own clock ticks, half a period later and at half the rate."""
    x = read_euroc_imu(imu_csv, raw=True)
    t = (x.time_origin_ns + np.round(x.t * 1e9)) * 1e-9
    acc, gyr = work / f"acc{int(shifted)}.txt", work / f"gyro{int(shifted)}.txt"
    np.savetxt(gyr, np.column_stack([t, x.gyro]), fmt=["%.6f"] + ["%d"] * 3)
    if shifted:
        half = 0.5 * float(np.median(np.diff(x.t)))
        sel = slice(0, None, 2)
        a = np.stack([np.interp(x.t[sel] + half, x.t, x.accel[:, c]) for c in range(3)], 1)
        np.savetxt(acc, np.column_stack([t[sel] + half, a]), fmt="%.6f")
    else:
        np.savetxt(acc, np.column_stack([t, x.accel]), fmt=["%.6f"] + ["%d"] * 3)
    return acc, gyr


@pytest.mark.slow
def test_imu_tk_two_files(work: Path, raw_run: tuple[Path, str],
                          counts_session: tuple[Path, dict[str, Any]],
                          capsys: pytest.CaptureFixture[str]) -> None:
    imu_csv, truth = counts_session
    ref = load(raw_run[0])
    for shifted in (False, True):
        acc, gyr = _triads(work, imu_csv, shifted)
        out = work / f"two{int(shifted)}.yaml"
        ok(run(["multipos", "--raw", "--accel", acc, "--gyro", gyr, "--out", out, "-q"],
               capsys))
        d = load(out)
        if not shifted:  # the same samples: the same calibration
            for name in ("accel_matrix", "gyro_matrix", "accel_bias", "gyro_bias"):
                assert np.allclose(d[name], ref[name], rtol=0, atol=1e-9), name
        assert_targets(errors(in_truth_units(out, truth), truth))
    bad = [(["--raw", "--accel", acc], 2, "no --gyro"),
           (["--raw", "--imu", imu_csv, "--accel", acc, "--gyro", gyr], 2, "--imu and --accel"),
           (["--raw", "--accel", acc, "--gyro", work / "missing.txt"], 2, "not found"),
           (["--raw", "--imu", imu_csv, "--gyro-unit", "deg/s"], 2, "leave those options out"),
           (["--imu", imu_csv, "--accel-scale", "0.0024"], 2, "pass --raw"),
           (["--raw", "--imu", imu_csv, "--accel-scale", "0.0024"], 2, "both --accel-scale"),
           (["--raw", "--imu", imu_csv, "--accel-scale", "1,2", "--gyro-scale", "1"], 2,
            "1 or 3"),
           (["--raw", "--imu", imu_csv, "--g-sensitivity", "yes"], 2,
            "--g-sensitivity.*'yes' is not one of 'auto', 'on', 'off'")]
    for args, code, pattern in bad:
        assert_error(run(["multipos", *args, "--out", work / "bad.yaml", "-q"], capsys), code,
                     pattern)


@pytest.mark.slow
def test_raw_prior_and_drift(work: Path, raw_run: tuple[Path, str],
                             counts_session: tuple[Path, dict[str, Any]],
                             capsys: pytest.CaptureFixture[str]) -> None:
    """Another session of the same part: the raw intrinsics as a prior (with a nominal, so the
    two files are in different units), and the drift check on its raw counts."""
    from mocap_calib.io.formats.euroc import write_euroc_imu
    from mocap_calib.sim.multipos import CountsSpec, simulate_multipos

    truth = counts_session[1]
    intr = {k: truth[k] for k in ("accel_matrix", "accel_bias", "gyro_matrix", "gyro_bias")}
    imu, other_truth = simulate_multipos(4, counts=CountsSpec(), **intr,
                                         g_sensitivity=truth["g_sensitivity"])
    other = write_euroc_imu(work / "other" / "data.csv", imu)
    c = truth["counts"]
    with_prior = work / "with_prior.yaml"
    text = ok(run(["multipos", "--raw", "--imu", other, "--prior", raw_run[0],
                   "--accel-scale", str(c["accel_scale"][0]), "--gyro-scale",
                   str(c["gyro_scale"][0]), "--out", with_prior], capsys))
    assert "prior               earlier result" in text and "scale error" in text
    assert load(with_prior)["raw_input"]["source"] == "given"
    assert_targets(errors(in_truth_units(with_prior, other_truth), other_truth))
    iv = np.asarray(other_truth["simulation"]["static_intervals_s"])
    t1 = float(np.mean(iv[np.argmin(np.abs(iv.mean(axis=1) - 100.0))]))
    drift = work / "drift_raw.yaml"
    out_text = ok(run(["drift", "--imu", other, "--calibration", raw_run[0],
                       "--segment-start", 35, "--segment-end", t1, "--out", drift], capsys))
    r = load(drift)
    print("drift with raw intrinsics:", {k: r[k] for k in ("tilt_drift_raw_deg",
                                                           "tilt_drift_cal_deg")})
    assert r["tilt_drift_raw_deg"] > 5.0 and r["tilt_drift_cal_deg"] < 0.3
    assert "raw counts converted" in out_text
    # An SI calibration as the prior of a raw session is refused.
    si = work / "si"
    ok(run(["simulate", si, "--protocol", "multipos", "--seed", 5], capsys))
    ok(run(["multipos", "--imu", si, "--out", work / "si.yaml", "-q"], capsys))
    assert_error(run(["multipos", "--raw", "--imu", other, "--prior", work / "si.yaml",
                      "--out", work / "bad.yaml", "-q"], capsys), 2, "SI units, this session")


def test_initial_rest_message_names_the_length(work: Path,
                                               counts_session: tuple[Path, dict[str, Any]],
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """The message names the initial rest's length once, not as a '50-50 s' range."""
    out = work / "flight"
    ok(run(["simulate", out, "--seed", 9, "--duration", 80], capsys))
    code, o, err = run(["multipos", "--imu", out / "mav0" / "imu0" / "data.csv",
                        "--init-static", 50, "--out", work / "bad.yaml", "-q"], capsys)
    assert_error((code, o, err), 3, "no initial static period.*at least 50 s")
    assert "50-50" not in err


def test_simulate_options_apply_to_their_protocol(work: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    assert_error(run(["simulate", work / "x", "--counts"], capsys), 2,
                 "--counts applies to --protocol multipos")
    assert_error(run(["simulate", work / "x", "--protocol", "multipos", "--effect",
                      "time_offset"], capsys), 2, "does not apply to --protocol multipos")
