"""End-to-end tests of the mocap-free IMU commands (``multipos``, ``allan``, ``drift``) through
``mocap_calib.cli.main.main`` on simulated files: accuracy against the simulator's truth, file
formats, and one-line errors with the right exit code for bad input."""

from __future__ import annotations

import contextlib
import io
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

# ``drift`` is not in the commands package's auto-import list yet: register it explicitly.
import mocap_calib.cli.commands.drift  # noqa: F401
from mocap_calib.cli.main import main
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.io.formats.euroc import write_euroc_imu
from mocap_calib.io.yaml_io import load_noise
from mocap_calib.sim.multipos import simulate_multipos
from mocap_calib.sim.static import simulate_static

KALIBR = ("gyroscope_noise_density", "gyroscope_random_walk",
          "accelerometer_noise_density", "accelerometer_random_walk")
INTRINSICS = ("accel_matrix", "accel_bias", "gyro_matrix", "gyro_bias")
DAY_NS = 86_400 * 10**9

# Allan log: the random walk K limits the accuracy, and its precision depends on how many
# crossover times (gyro: ~15 s for the ADIS16448 defaults) the log spans, not on the rate.
# Monte Carlo of characterise_noise on simulate_static at 20 Hz, 200 seeds each: the gyro K
# (mean over axes) had a standard deviation of 2.5 % / 2.1 % / 1.9 % and a worst case of
# 10.8 % / 7.7 % / 5.5 % for 4 / 5 / 6 h logs; the other three keys stayed within 2 % (white
# noise ~0.1 %). 6 h makes "within 10 %" a > 5-sigma test; 20 Hz keeps the file at 432 k rows
# (simulate + allan ~6 s).
ALLAN_HOURS = 6.0
ALLAN_RATE = 20.0


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------

def cli(args: list[Any]) -> tuple[int, str, str]:
    """Run the CLI, capturing its output (for module-scoped fixtures, where capsys is not
    available)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def run(args: list[Any], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def ok(result: tuple[int, str, str]) -> str:
    code, out, err = result
    assert code == 0, f"exit {code}\n{out}\n{err}"
    return out


def assert_error(result: tuple[int, str, str], code: int, pattern: str) -> None:
    """Exit ``code``, exactly one ``error:`` line matching ``pattern``, no traceback."""
    got, out, err = result
    assert "Traceback" not in out + err, err
    assert got == code, f"exit {got}, expected {code}\n{out}\n{err}"
    errors = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1, err
    assert re.search(pattern, errors[0]), errors[0]


def load(path: Path) -> dict[str, Any]:
    return yaml.safe_load(path.read_text())


def intrinsics_errors(d: dict[str, Any], truth: dict[str, Any]) -> dict[str, float]:
    """Worst scale error (relative), misalignment (deg) and bias errors against the truth."""
    out = {}
    off = ~np.eye(3, dtype=bool)
    for sensor in ("accel", "gyro"):
        M = np.asarray(d[f"{sensor}_matrix"])
        T = np.asarray(truth[f"{sensor}_matrix"])
        out[f"{sensor}_scale"] = float(np.max(np.abs(np.diag(M) / np.diag(T) - 1.0)))
        # Misalignment angle of an entry: off-diagonal error relative to its row's scale.
        out[f"{sensor}_misalignment_deg"] = float(np.degrees(np.max(np.abs(
            (M - T) / np.diag(T)[:, None])[off])))
        out[f"{sensor}_bias"] = float(np.max(np.abs(np.asarray(d[f"{sensor}_bias"])
                                                    - np.asarray(truth[f"{sensor}_bias"]))))
    return out


def assert_within_targets(e: dict[str, float]) -> None:
    assert e["accel_scale"] < 1e-3 and e["gyro_scale"] < 1e-3, e
    assert e["accel_misalignment_deg"] < 0.05 and e["gyro_misalignment_deg"] < 0.05, e
    assert e["accel_bias"] < 5e-3, e
    assert e["gyro_bias"] < 1e-4, e


# --------------------------------------------------------------------------------------------
# Fixtures: simulated files, each command run once
# --------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("imu_tools")


@pytest.fixture(scope="module")
def multipos_session(work: Path) -> tuple[Path, dict[str, Any]]:
    """A multi-position session written by ``simulate --protocol multipos``."""
    out = work / "mp"
    ok(cli(["simulate", out, "--protocol", "multipos", "--seed", 3]))
    return out / "mav0" / "imu0" / "data.csv", load(out / "truth.yaml")


@pytest.fixture(scope="module")
def multipos_run(work: Path, multipos_session: tuple[Path, dict[str, Any]]
                 ) -> tuple[Path, str]:
    imu, _ = multipos_session
    out = work / "intrinsics.yaml"
    return out, ok(cli(["multipos", "--imu", imu, "--out", out]))


@pytest.fixture(scope="module")
def earlier_sessions(work: Path, multipos_session: tuple[Path, dict[str, Any]]
                     ) -> list[tuple[Path, dict[str, Any]]]:
    """Two earlier sessions of the same IMU (same intrinsics, other noise), 60 and 30 days
    before, and their multipos intrinsics files."""
    _, truth = multipos_session
    t_new = 1_600_000_000_000_000_000  # the simulator's default first stamp
    out = []
    for k, days in enumerate((60, 30)):
        imu, tr = simulate_multipos(seed=100 + k, time_origin_ns=t_new - days * DAY_NS,
                                    **{name: truth[name] for name in INTRINSICS})
        csv = write_euroc_imu(work / f"earlier{k}" / "data.csv", imu)
        ok(cli(["multipos", "--imu", csv, "--out", work / f"earlier{k}.yaml", "-q"]))
        out.append((work / f"earlier{k}.yaml", {**tr, "csv": csv}))
    return out


@pytest.fixture(scope="module")
def static_log(work: Path) -> tuple[Path, dict[str, Any]]:
    out = work / "static"
    ok(cli(["simulate", out, "--protocol", "static", "--seed", 1,
            "--duration", ALLAN_HOURS * 3600, "--imu-rate", ALLAN_RATE]))
    return out / "mav0" / "imu0" / "data.csv", load(out / "truth.yaml")


@pytest.fixture(scope="module")
def allan_run(work: Path, static_log: tuple[Path, dict[str, Any]]) -> tuple[Path, Path, str]:
    imu, _ = static_log
    noise, rrd = work / "noise.yaml", work / "allan.rrd"
    return noise, rrd, ok(cli(["allan", "--imu", imu, "--out", noise, "--rrd", rrd]))


@pytest.fixture(scope="module")
def flight(work: Path) -> Path:
    """A 40 s mocap flight (mav0 folder with imu0 and vicon0, truth.yaml)."""
    out = work / "flight"
    ok(cli(["simulate", out, "--seed", 5, "--duration", 40]))
    return out


# --------------------------------------------------------------------------------------------
# multipos
# --------------------------------------------------------------------------------------------

def test_multipos_recovers_the_truth(multipos_run: tuple[Path, str],
                                     multipos_session: tuple[Path, dict[str, Any]]) -> None:
    path, out = multipos_run
    d = load(path)
    e = intrinsics_errors(d, multipos_session[1])
    print("multipos errors:", e)
    assert_within_targets(e)
    # The conventions' keys, M_a lower-triangular, sigmas, residuals and diagnostics.
    assert set(INTRINSICS) <= set(d) and set(d["sigma"]) == set(INTRINSICS)
    assert np.all(np.triu(np.asarray(d["accel_matrix"]), 1) == 0.0)
    assert {"accel_rms_mps2", "gyro_rms_rad"} <= set(d["residuals"])
    assert d["diagnostics"]["n_static_intervals"] == 40
    assert d["diagnostics"]["poorly_determined"] == []
    # The printed table.
    for text in ("accel scale error x", "gyro misalignment zy", "gyro bias z", "%", "deg",
                 "1-sigma", "residual RMS", "threshold multiple", "40 static intervals",
                 "poorly determined   none"):
        assert text in out, text
    row = re.search(r"accel scale error z\s+([-+0-9.]+)\s+([0-9.]+)\s+%", out)
    assert row is not None
    M_a = np.asarray(d["accel_matrix"])
    assert float(row.group(1)) == pytest.approx(100 * (M_a[2, 2] - 1), abs=1e-4)


@pytest.mark.slow
def test_multipos_with_one_and_two_priors(work: Path,
                                          multipos_session: tuple[Path, dict[str, Any]],
                                          multipos_run: tuple[Path, str],
                                          earlier_sessions: list[tuple[Path, dict[str, Any]]],
                                          capsys: pytest.CaptureFixture[str]) -> None:
    imu, truth = multipos_session
    plain = load(multipos_run[0])
    for k, (path, tr) in enumerate(earlier_sessions):
        assert_within_targets(intrinsics_errors(load(path), tr))
        assert load(path)["diagnostics"]["session_time_ns"] == int(
            1_600_000_000_000_000_000 - (60, 30)[k] * DAY_NS)

    one = work / "with_one_prior.yaml"
    out = ok(run(["multipos", "--imu", imu, "--out", one, "--prior", earlier_sessions[1][0]],
                 capsys))
    assert "prior               earlier result" in out

    two = work / "with_trend.yaml"
    out = ok(run(["multipos", "--imu", imu, "--out", two, "--prior", earlier_sessions[0][0],
                  "--prior", earlier_sessions[1][0]], capsys))
    assert "prior               trend of 2 results" in out
    for path in (one, two):
        d = load(path)
        e = intrinsics_errors(d, truth)
        print(path.name, e)
        assert_within_targets(e)
        # The prior adds information on the matrices: smaller sigmas than without.
        for name in ("accel_matrix", "gyro_matrix"):
            free = np.tril(np.ones((3, 3), bool)) if name == "accel_matrix" else np.ones(
                (3, 3), bool)
            assert np.all(np.asarray(d["sigma"][name])[free]
                          < np.asarray(plain["sigma"][name])[free]), name
        # Biases are not constrained by default: the gyro bias is this session's own.
        assert d["gyro_bias"] == pytest.approx(plain["gyro_bias"], abs=1e-12)
    assert "trend of 2 results" in load(two)["diagnostics"]["prior"]

    # --prior-biases: the biases are constrained too (same IMU, same biases here).
    biased = work / "with_bias_prior.yaml"
    ok(run(["multipos", "--imu", imu, "--out", biased, "--prior", earlier_sessions[1][0],
            "--prior-biases", "-q"], capsys))
    d = load(biased)
    assert_within_targets(intrinsics_errors(d, truth))
    assert np.all(np.asarray(d["sigma"]["gyro_bias"]) < np.asarray(plain["sigma"]["gyro_bias"]))
    assert "gyro_bias" in d["diagnostics"]["prior"]


def test_multipos_reads_a_generic_csv_with_units(work: Path, multipos_run: tuple[Path, str],
                                                 multipos_session: tuple[Path, dict[str, Any]],
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """The same session as a generic CSV (s, deg/s, g, other column order) gives the same
    intrinsics as the EuRoC file."""
    from mocap_calib.io.formats.euroc import read_euroc_imu

    imu = read_euroc_imu(multipos_session[0])
    csv = work / "generic.csv"
    table = np.column_stack([imu.t, imu.accel / 9.80665, np.degrees(imu.gyro)])
    np.savetxt(csv, table, delimiter=",", fmt="%.12g", header="time,ax,ay,az,gx,gy,gz")
    out = work / "generic_intrinsics.yaml"
    ok(run(["multipos", "--imu", csv, "--columns", "t=0,accel=1:4,gyro=4:7", "--gyro-unit",
            "deg/s", "--accel-unit", "g", "--time-unit", "s", "--out", out, "-q"], capsys))
    a, b = load(out), load(multipos_run[0])
    for name in INTRINSICS:
        assert np.allclose(a[name], b[name], rtol=0, atol=1e-6), name


# --------------------------------------------------------------------------------------------
# allan
# --------------------------------------------------------------------------------------------

@pytest.mark.slow
def test_allan_densities_within_10_percent(allan_run: tuple[Path, Path, str],
                                           static_log: tuple[Path, dict[str, Any]]) -> None:
    noise, _, out = allan_run
    d = load(noise)
    truth = static_log[1]
    rel = {k: d[k] / truth[k] - 1.0 for k in KALIBR}
    print("allan relative errors:", rel)
    for k in KALIBR:
        assert abs(rel[k]) < 0.10, (k, rel)
    for sensor in ("gyroscope", "accelerometer"):
        assert len(d[f"{sensor}_bias_instability"]) == 3
        assert all(d["per_axis"][sensor]["random_walk_resolved"])
    assert d["aggregate"] == "mean" and d["update_rate"] == pytest.approx(ALLAN_RATE)
    assert "unobservable" not in d
    for text in ("noise density N", "random walk K", "bias instab. B", "gyroscope_random_walk:",
                 "accelerometer_noise_density:"):
        assert text in out, text


def test_allan_recording_has_the_log_log_curves(allan_run: tuple[Path, Path, str]) -> None:
    from rerun.chunk import RrdReader

    from mocap_calib.viz.allan_plot import TIMELINE

    noise, rrd, _ = allan_run
    d = load(noise)
    series: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for chunk in RrdReader(rrd).stream():
        b = chunk.to_record_batch()
        if TIMELINE in b.schema.names and "Scalars:scalars" in b.schema.names:
            series[chunk.entity_path.lstrip("/")] = (
                b.column(TIMELINE).to_numpy().astype(float),
                np.concatenate(b.column("Scalars:scalars").to_pylist()))
    for sensor in ("gyroscope", "accelerometer"):
        for axis in "xyz":
            for name in ("adev", "fit", "white_noise", "random_walk", "bias_instability"):
                assert f"{sensor}/{axis}/{name}" in series, (sensor, axis, name)
    x, y = series["gyroscope/x/adev"]
    tau = np.asarray(d["allan"]["gyroscope"]["tau"])
    assert np.allclose(x, np.round(1000 * np.log10(tau)))
    assert np.allclose(y, np.log10(d["allan"]["gyroscope"]["adev"][0]))
    # The white-noise line reads N at tau = 1 s (x = 0).
    xw, yw = series["gyroscope/x/white_noise"]
    N = d["per_axis"]["gyroscope"]["noise_density"][0]
    assert np.allclose(yw, np.log10(N) - 0.5 * xw / 1000, atol=1e-3)
    # The viewer's own check: the file loads and its data match their schemas.
    viewer = Path(sys.executable).parent / "rerun"
    if viewer.is_file():
        proc = subprocess.run([str(viewer), "rrd", "verify", str(rrd)], capture_output=True,
                              text=True, timeout=60)
        assert proc.returncode == 0, proc.stdout + proc.stderr


def test_allan_output_is_a_calibrate_noise_file(work: Path, allan_run: tuple[Path, Path, str],
                                                flight: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    noise_file = allan_run[0]
    d = load(noise_file)
    model = load_noise(noise_file)
    for k in KALIBR:
        assert getattr(model, k) == pytest.approx(d[k])
    # And 'calibrate --noise' takes it: calibrate on [0, 25] s of a flight, then check the
    # drift on the held-out [26, 39] s against the mocap.
    cal = work / "calib.yaml"
    ok(run(["calibrate", flight, "--noise", noise_file, "--end", 25, "--out", cal, "-q"],
           capsys))
    used = load(cal)["noise"]
    assert used["gyroscope_noise_density"] == pytest.approx(d["gyroscope_noise_density"])
    assert used["accelerometer_random_walk"] == pytest.approx(d["accelerometer_random_walk"])
    out_file = work / "drift_calibrate.yaml"
    out = ok(run(["drift", "--imu", flight, "--mocap", flight, "--calibration", cal,
                  "--segment-start", 26, "--segment-end", 39, "--out", out_file, "-q"], capsys))
    r = load(out_file)
    print("drift after calibrate:", {k: r[k] for k in ("tilt_drift_raw_deg",
                                                       "tilt_drift_cal_deg", "reduction")})
    assert r["initial_source"] == r["reference_source"] == "reference"
    assert r["tilt_drift_cal_deg"] < 0.5 and r["reduction"] > 0.8
    assert "initial attitude: mocap" in out


# --------------------------------------------------------------------------------------------
# drift
# --------------------------------------------------------------------------------------------

def test_drift_with_mocap_and_the_true_calibration(work: Path, flight: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    out_file = work / "drift_truth.yaml"
    out = ok(run(["drift", "--imu", flight / "mav0" / "imu0" / "data.csv", "--mocap",
                  flight / "mav0" / "vicon0" / "data.csv", "--calibration",
                  flight / "truth.yaml", "--segment-start", 5, "--segment-end", 35, "--out",
                  out_file], capsys))
    r = load(out_file)
    print("drift with the true calibration:", {k: r[k] for k in (
        "tilt_drift_raw_deg", "tilt_drift_cal_deg", "reduction")})
    assert r["t0"] == pytest.approx(5.0, abs=0.01) and r["t1"] == pytest.approx(35.0, abs=0.01)
    assert r["reduction"] > 0.8 and r["tilt_drift_cal_deg"] < 0.5
    assert r["calibration"]["kind"] == "calibrate"
    # Along the mocap series the calibrated integration stays close to the reference.
    assert np.max(r["series"]["tilt_cal_deg"]) < 0.5 < np.max(r["series"]["tilt_raw_deg"])
    for text in ("roll drift", "pitch drift", "raw gyro", "calibrated", "reduction"):
        assert text in out


def test_drift_with_multipos_intrinsics_at_rest(work: Path, multipos_run: tuple[Path, str],
                                                earlier_sessions: list[tuple[Path, Any]],
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Intrinsics from one session, checked on another session of the same IMU between two
    rest periods (roll and pitch from the accelerometer)."""
    _, tr = earlier_sessions[0]
    iv = np.asarray(tr["simulation"]["static_intervals_s"])
    t1 = float(np.mean(iv[np.argmin(np.abs(iv.mean(axis=1) - 100.0))]))
    out_file = work / "drift_multipos.yaml"
    out = ok(run(["drift", "--imu", tr["csv"], "--calibration", multipos_run[0],
                  "--segment-start", 35, "--segment-end", t1, "--out", out_file], capsys))
    r = load(out_file)
    print("drift with multipos intrinsics:", {k: r[k] for k in (
        "duration", "tilt_drift_raw_deg", "tilt_drift_cal_deg", "reduction")})
    assert r["initial_source"] == r["reference_source"] == "accel"
    assert r["calibration"]["kind"] == "multipos"
    # Calibrated: what is left is the gyro bias error (target < 1e-4 rad/s: < 0.37 deg here).
    assert r["tilt_drift_raw_deg"] > 5.0 and r["tilt_drift_cal_deg"] < 0.3
    assert r["reduction"] > 0.95
    assert "accelerometer at rest" in out


# --------------------------------------------------------------------------------------------
# Bad input: one 'error:' line and the exit code, never a traceback
# --------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def bad_files(work: Path, flight: Path) -> dict[str, Path]:
    """Logs that are wrong for one command or another."""
    files: dict[str, Path] = {}
    garbage = work / "garbage.csv"
    garbage.write_text("this is not\na data file\n")
    files["garbage"] = garbage
    plain = work / "plain.csv"
    plain.write_text("".join(f"{i * 0.01:.2f},0,0,0,0,0,9.81\n" for i in range(200)))
    files["no_header"] = plain
    # Static logs: 120 s (long enough for multipos, but one orientation), 40 s (too short for
    # multipos), 5 min (too short for allan).
    for name, dur in (("static_120s", 120.0), ("static_40s", 40.0), ("static_5min", 300.0)):
        imu, _ = simulate_static(7, dur, 100.0)
        files[name] = write_euroc_imu(work / name / "data.csv", imu)
    # 20 min of a gyro whose random walk is far below its white noise: not resolved.
    imu, _ = simulate_static(4, 1200.0, ALLAN_RATE, noise=NoiseModel(gyroscope_random_walk=1e-7))
    files["short_rw_20min"] = write_euroc_imu(work / "short_rw" / "data.csv", imu)
    # A 15 min log with a turn in the middle (allan: not static).
    imu, _ = simulate_static(8, 900.0, ALLAN_RATE)
    gyro = imu.gyro.copy()
    gyro[(imu.t > 400) & (imu.t < 430), 2] += 0.5
    moving = type(imu)(imu.t, gyro, imu.accel, imu.time_origin_ns, imu.source)
    files["moving_15min"] = write_euroc_imu(work / "moving" / "data.csv", moving)
    # A 60 s flight: long enough for multipos' length check, but it never rests.
    out = work / "flight60"
    ok(cli(["simulate", out, "--seed", 9, "--duration", 60]))
    files["flight60"] = out / "mav0" / "imu0" / "data.csv"
    files["flight_truth"] = flight / "truth.yaml"
    return files


def test_bad_input_multipos(work: Path, bad_files: dict[str, Path], flight: Path,
                            allan_run: tuple[Path, Path, str],
                            multipos_session: tuple[Path, dict[str, Any]],
                            capsys: pytest.CaptureFixture[str]) -> None:
    imu = multipos_session[0]
    out = ["--out", work / "bad.yaml", "-q"]
    cases: list[tuple[list[Any], int, str]] = [
        (["--imu", work / "missing.csv"], 2, "file not found"),
        ([], 2, "no --imu"),
        (["--imu", flight / "mav0" / "vicon0" / "data.csv"], 2, "pose file"),
        (["--imu", bad_files["garbage"]], 2, "garbage.csv"),
        (["--imu", bad_files["no_header"]], 2, "--columns"),
        (["--imu", bad_files["flight60"]], 3, "no initial static period.*--init-static"),
        (["--imu", bad_files["static_120s"]], 3, r"found 1 static orientations"),
        (["--imu", bad_files["static_40s"]], 3, "too short"),
        (["--imu", imu, "--prior", allan_run[0]], 2, "noise file.*not multipos intrinsics"),
        (["--imu", imu, "--prior", bad_files["flight_truth"]], 2,
         "calibrate' result, not multipos intrinsics"),
        (["--imu", imu, "--prior", multipos_session[0].parents[2] / "truth.yaml"], 2,
         "no 'sigma"),
        (["--imu", imu, "--prior", work / "missing_prior.yaml"], 2, "not found"),
        (["--imu", imu, "--gravity", 1.0], 2, "--gravity 1"),
        (["--imu", imu, "--init-static", 1], 2, "--init-static 1 s is shorter"),
    ]
    for args, code, pattern in cases:
        assert_error(run(["multipos", *args, *out], capsys), code, pattern)
    assert not (work / "bad.yaml").exists()


def test_bad_input_allan(work: Path, bad_files: dict[str, Path],
                         static_log: tuple[Path, dict[str, Any]],
                         multipos_session: tuple[Path, dict[str, Any]],
                         capsys: pytest.CaptureFixture[str]) -> None:
    out = ["--out", work / "bad_noise.yaml", "-q"]
    cases: list[tuple[list[Any], int, str]] = [
        (["--imu", work / "missing.csv"], 2, "file not found"),
        (["--imu", bad_files["garbage"]], 2, "garbage.csv"),
        (["--imu", bad_files["static_5min"]], 3, "needs at least 10 min"),
        (["--imu", bad_files["moving_15min"]], 3, "not static"),
        (["--imu", bad_files["short_rw_20min"]], 3,
         "gyroscope random walk .* not resolved .* pass --allow-unresolved"),
        (["--imu", multipos_session[0]], 3, "min long"),
        (["--imu", static_log[0], "--aggregate", "median"], 2,
         "--aggregate.*'median' is not one of 'mean', 'max'"),
        (["--imu", static_log[0], "--tau-min", -1], 2, "--tau-min"),
    ]
    for args, code, pattern in cases:
        assert_error(run(["allan", *args, *out], capsys), code, pattern)
    assert not (work / "bad_noise.yaml").exists()


def test_bad_input_drift(work: Path, bad_files: dict[str, Path], flight: Path,
                         multipos_run: tuple[Path, str], allan_run: tuple[Path, Path, str],
                         multipos_session: tuple[Path, dict[str, Any]],
                         capsys: pytest.CaptureFixture[str]) -> None:
    imu = flight / "mav0" / "imu0" / "data.csv"
    mocap = flight / "mav0" / "vicon0" / "data.csv"
    truth = flight / "truth.yaml"
    iv = np.asarray(multipos_session[1]["simulation"]["static_intervals_s"])
    mid_rotation = float(0.5 * (iv[5, 1] + iv[6, 0]))
    def seg(start: float, end: float) -> list[Any]:
        return ["--segment-start", start, "--segment-end", end]

    cases: list[tuple[list[Any], int, str]] = [
        (["--imu", work / "missing.csv", "--calibration", truth, *seg(1, 5)], 2,
         "file not found"),
        (["--imu", imu, "--calibration", work / "missing.yaml", *seg(1, 5)], 2, "not found"),
        (["--imu", imu, "--calibration", allan_run[0], *seg(1, 5)], 2,
         "noise file.*not a calibration"),
        (["--imu", bad_files["garbage"], "--calibration", truth, *seg(1, 5)], 2,
         "garbage.csv"),
        (["--imu", imu, "--mocap", mocap, "--calibration", truth, *seg(5, 5)], 2,
         "must be before --segment-end"),
        (["--imu", imu, "--mocap", mocap, "--calibration", truth, *seg(10, 2)], 2,
         "must be before --segment-end"),
        (["--imu", imu, "--mocap", mocap, "--calibration", truth, *seg(10, 100)], 2,
         "outside the IMU log"),
        (["--imu", imu, "--mocap", mocap, "--calibration", truth, *seg(-5, 10)], 2,
         "--segment-start -5.0: must be at least 0 s"),
        (["--imu", imu, "--mocap", mocap, "--calibration", multipos_run[0], *seg(1, 5)], 2,
         "no T_marker_imu"),
        # No mocap: roll and pitch must come from the accelerometer, but the drone flies.
        (["--imu", imu, "--calibration", truth, *seg(5, 15)], 3, "not at rest.*pass --mocap"),
        # Multipos session: start at rest, end in the middle of a rotation.
        (["--imu", multipos_session[0], "--calibration", multipos_run[0], *seg(35, mid_rotation)],
         3, "not at rest"),
    ]
    for args, code, pattern in cases:
        assert_error(run(["drift", *args, "-q"], capsys), code, pattern)


def test_allan_allow_unresolved_writes_null_random_walk(work: Path, bad_files: dict[str, Path],
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    noise_file = work / "partial_noise.yaml"
    out = ok(run(["allan", "--imu", bad_files["short_rw_20min"], "--out", noise_file,
                  "--allow-unresolved", "--aggregate", "max", "-q"], capsys))
    d = load(noise_file)
    assert d["gyroscope_random_walk"] is None and "gyroscope_random_walk" in d["unobservable"]
    assert d["accelerometer_random_walk"] is not None and d["aggregate"] == "max"
    assert "UNOBSERVABLE gyroscope_random_walk" in out
    # calibrate --noise keeps its default where the file says null.
    model = load_noise(noise_file)
    assert model.gyroscope_random_walk == NoiseModel().gyroscope_random_walk
    assert model.gyroscope_noise_density == pytest.approx(d["gyroscope_noise_density"])


def test_imu_commands_import_only_workflows() -> None:
    """The multipos, allan and drift commands parse options and call one workflow: their
    modules import nothing of io, core, viz or report."""
    import ast

    import mocap_calib.cli.commands as commands

    root = Path(commands.__file__).parent
    for name in ("multipos", "allan", "drift"):
        tree = ast.parse((root / f"{name}.py").read_text())
        mods = [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module]
        mods += [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        ours = [m for m in mods if m.startswith("mocap_calib")]
        assert ours and all(m.startswith(("mocap_calib.workflows", "mocap_calib.cli"))
                            for m in ours), (name, ours)
