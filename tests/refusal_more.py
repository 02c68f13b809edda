"""More corpus cases: column maps that must not be dropped, files a column short or in
another delimiter, swapped IMU columns, one-axis motion that fit upside down, marker swaps
(isolated: removed, the session calibrates; in runs: their holes leave too few intervals),
``--start`` beyond the session. Built from the helpers of :mod:`refusal_corpus`; :data:`ALL_CASES`
is its ``CASES`` and these."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from refusal_corpus import CASES, Case, Expect, _calibrate, _imu, _mocap, clean, mav0, session

from mocap_calib.core.model import so3
from mocap_calib.core.model.types import MocapPoses
from mocap_calib.io.formats.euroc import write_mav0
from mocap_calib.io.formats.tum import write_tum


def _poses_file(sep: str, header: bool = True, drop: int | None = None
                ) -> Callable[[Path], list[str]]:
    """The clean session's EuRoC pose file rewritten with another delimiter, without its
    header, or without one column; given with --imu/--mocap."""
    def build(d: Path) -> list[str]:
        root = write_mav0(d, clean().imu, clean().mocap)
        rows = [[t.strip() for t in line.split(",")]
                for line in (root / "vicon0" / "data.csv").read_text().splitlines()]
        if drop is not None:
            rows = [r[:drop] + r[drop + 1:] for r in rows]
        out = d / "poses.txt"
        out.write_text("\n".join(sep.join(r) for r in rows[0 if header else 1:]) + "\n")
        return ["--imu", str(root / "imu0" / "data.csv"), "--mocap", str(out)]
    return build


def _tum_seven_columns(d: Path) -> list[str]:
    root = write_mav0(d, clean().imu, clean().mocap)
    tum = write_tum(d / "poses.txt", clean().mocap)
    tum.write_text("\n".join(" ".join(line.split()[:7]) if not line.startswith("#") else line
                             for line in tum.read_text().splitlines()) + "\n")
    return ["--imu", str(root / "imu0" / "data.csv"), "--mocap", str(tum)]


def marker_swaps(fraction: float = 0.05, seed: int = 1, run: int = 1) -> MocapPoses:
    """Samples where the rigid body was solved with its markers swapped: the pose turned
    120 deg about a body axis and shifted 3 cm; isolated, or in runs of ``run`` frames."""
    m = clean().mocap
    starts = np.random.default_rng(seed).choice(np.arange(2, len(m.t) - 2 - run),
                                                size=int(fraction * len(m.t) / run),
                                                replace=False)
    k = np.unique((starts[:, None] + np.arange(run)[None, :]).ravel())
    q, p = m.quat_wxyz.copy(), m.position.copy()
    q[k] = so3.rotmat_to_quat(so3.quat_to_rotmat(q[k]) @ so3.exp(np.radians([0.0, 0.0, 120.0])))
    p[k] += [0.03, 0.0, 0.0]
    return _mocap(clean(), q, p)


def _one_axis(motion: str) -> Callable[[Path], list[str]]:
    # Seed 4, 30 s: a session whose fit turns gravity upside down (2 g of accel bias).
    def build(d: Path) -> list[str]:
        s = session(seed=4, motion=motion, duration=30.0)
        return mav0(s.imu, s.mocap)(d)
    return build


MORE_CASES: list[Case] = [
    Case("columns_five_for_three", "option files",
         "--columns accel=4:9 on EuRoC files (five columns for a 3-vector)",
         _calibrate(mav0(None, None, "--columns", "accel=4:9")),
         Expect(2, ("--columns", "accel= names 5 columns", "3"))),
    Case("columns_on_euroc_used", "option files",
         "--columns that swaps gyro and accel, on EuRoC files",
         _calibrate(mav0(None, None, "--columns", "t=0,gyro=4:7,accel=1:4")),
         Expect(2, ("swapped",))),
    Case("mocap_tab_separated", "file layout", "EuRoC pose file with tabs for commas",
         _calibrate(_poses_file("\t")), Expect(0)),
    Case("mocap_semicolon_separated", "file layout", "EuRoC pose file with semicolons",
         _calibrate(_poses_file(";")), Expect(0)),
    Case("mocap_tab_no_header", "file layout",
         "EuRoC pose rows, tab-separated, without the header",
         _calibrate(_poses_file("\t", header=False)),
         Expect(2, ("nanosecond", "without a header", "EuRoC", "--columns"))),
    Case("mocap_missing_qz", "file layout", "EuRoC pose file without its q_z column",
         _calibrate(_poses_file(",", drop=7)),
         Expect(2, ("EuRoC mocap rows have 8 columns", "this one has 7", "q_RS_z"))),
    Case("mocap_missing_column_no_header", "file layout",
         "EuRoC pose rows without header and one column",
         _calibrate(_poses_file(",", header=False, drop=2)),
         Expect(2, ("EuRoC mocap rows have 8 columns", "this one has 7"))),
    Case("tum_seven_columns", "file layout", "TUM trajectory of 7 columns",
         _calibrate(_tum_seven_columns),
         Expect(2, ("TUM rows have 8 columns", "this one has 7"))),
    Case("gyro_accel_swapped", "conventions", "gyro and accel columns swapped",
         _calibrate(lambda d: mav0(_imu(clean(), gyro=clean().imu.accel,
                                        accel=clean().imu.gyro))(d)),
         Expect(2, ("swapped", "swap them"))),
    Case("turntable_upside_down", "degenerate",
         "turntable whose fit turns gravity upside down",
         _calibrate(_one_axis("turntable")),
         Expect(3, ("one axis only", "turntable", "accelerometer bias", "gravity",
                    "lever arm", "tilts the body"))),
    Case("planar_upside_down", "degenerate",
         "ground robot whose fit turns gravity upside down",
         _calibrate(_one_axis("planar")),
         Expect(3, ("one axis only", "ground robot", "accelerometer bias", "gravity"))),
    Case("marker_swaps", "faults", "5 % isolated marker swaps",
         _calibrate(lambda d: mav0(None, marker_swaps())(d)),
         Expect(0, notes=("marker swaps", "were removed"))),
    Case("marker_swap_runs", "faults", "15 % of the frames marker-swapped in runs of 3",
         _calibrate(lambda d: mav0(None, marker_swaps(0.15, run=3))(d)),
         Expect(3, ("marker swaps", "were removed", "mocap samples", "holes"))),
    Case("start_beyond_session", "option values", "--start 100 on a 30 s session",
         _calibrate(mav0(None, None, "--start", "100")),
         Expect(2, ("--start 100", "spans 0 to 30.0 s"))),
]

#: The whole corpus (tests/test_refusals.py, scripts/refusal_table.py).
ALL_CASES: list[Case] = [*CASES, *MORE_CASES]


# --- Outputs, option files, priors, exports and batch options (safety) ----------------------
# Careless and hostile inputs must never lose a user's file, crash, leak processes or pass
# silently wrong. Built on the clean session; every case here is refused before any work but
# the last one (a name that is not UTF-8), which must give the right result.

def _safety_mav0(d: Path) -> Path:
    """The clean session as a mav0 folder in ``d``; returns the mav0 folder."""
    return write_mav0(d, clean().imu, clean().mocap)


def _truth_file(d: Path, name: str = "calib.yaml", **changes: object) -> Path:
    """The clean session's truth as a calibration file, with plausible sigmas and
    ``changes`` (``"T_marker_imu.translation"`` goes into its mapping)."""
    import yaml

    t = yaml.safe_load(yaml.safe_dump(clean().truth))
    t["sigma"] = {"gyro_bias": [1e-4] * 3, "accel_bias": [1e-3] * 3, "rotation": [1e-3] * 3,
                  "translation": [1e-3] * 3, "gravity_in_mocap": [1e-3] * 2,
                  "time_offset": 1e-4}
    for key, value in changes.items():
        *parents, last = key.split(".")
        node = t
        for p in parents:
            node = node[p]
        node[last] = value
    path = d / name
    path.write_text(yaml.safe_dump(t))
    return path


def _out_is_imu(d: Path) -> list[str]:
    root = _safety_mav0(d)
    imu = root / "imu0" / "data.csv"
    return ["calibrate", "--imu", str(imu), "--mocap", str(root / "vicon0" / "data.csv"),
            "--out", str(imu)]


def _out_is_html(d: Path) -> list[str]:
    _safety_mav0(d)
    return ["calibrate", str(d), "--out", str(d / "r.yaml"), "--html", str(d / "r.yaml")]


def _export_onto_itself(d: Path) -> list[str]:
    calib = _truth_file(d)
    return ["export", str(calib), "--to", "kalibr", "--imu-rate", "200", "--out", str(calib)]


def _groundtruth_sidecar_onto_calibration(d: Path) -> list[str]:
    _safety_mav0(d)
    calib = _truth_file(d)
    return ["groundtruth", str(d), "--calibration", str(calib), "--out", str(d / "calib.csv")]


def _with_prior(**changes: object) -> Callable[[Path], list[str]]:
    def build(d: Path) -> list[str]:
        _safety_mav0(d)
        prior = _truth_file(d, "prior.yaml", **changes)
        return ["calibrate", str(d), "--prior", str(prior), "--out", str(d / "calib.yaml")]
    return build


def _prior_moved(d: Path) -> list[str]:
    """A --prior (the truth) whose lever arm is 50 mm off along x, with a 0.2 mm sigma."""
    t = clean().truth["T_marker_imu"]["translation"]
    return _with_prior(**{"T_marker_imu.translation": [t[0] + 0.05, t[1], t[2]],
                          "sigma.translation": [2e-4] * 3})(d)


def _with_option_file(option: str, text: str) -> Callable[[Path], list[str]]:
    def build(d: Path) -> list[str]:
        _safety_mav0(d)
        (d / "opt.yaml").write_text(text)
        return ["calibrate", str(d), option, str(d / "opt.yaml"), "--out", str(d / "calib.yaml")]
    return build


def _batch(manifest_text: Callable[[Path], str], *extra: str) -> Callable[[Path], list[str]]:
    def build(d: Path) -> list[str]:
        _safety_mav0(d)
        (d / "manifest.yaml").write_text(manifest_text(d))
        return ["batch", str(d / "manifest.yaml"), "--out", str(d / "out"), "--quiet", *extra]
    return build


def _one_session(d: Path, sid: str = "one", extra: str = "") -> str:
    return (f"sessions:\n  - id: '{sid}'\n    imu_id: a\n    date: 2024-03-01\n    mav0: {d}\n"
            f"{extra}")


def _alias_bomb(d: Path) -> str:
    lines = ['a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for k in range(1, 9):
        prev, name = chr(96 + k), chr(97 + k)
        lines.append(f"{name}: &{name} [" + ", ".join([f"*{prev}"] * 9) + "]")
    return "\n".join(lines) + f"\nsessions:\n  - id: *i\n    imu_id: a\n    mav0: {d}\n"


def _export_with(target: str, **changes: object) -> Callable[[Path], list[str]]:
    def build(d: Path) -> list[str]:
        calib = _truth_file(d, **changes)
        return ["export", str(calib), "--to", target, "--imu-rate", "200", "--out",
                str(d / f"exported.{target}")]
    return build


def _groundtruth_rate(d: Path) -> list[str]:
    _safety_mav0(d)
    return ["groundtruth", str(d), "--calibration", str(_truth_file(d)), "--rate", "100000",
            "--out", str(d / "gt.csv")]


def _name_not_utf8(d: Path) -> list[str]:
    import os

    folder = d / os.fsdecode(b"session\xff")
    write_mav0(folder, clean().imu, clean().mocap)
    return ["calibrate", str(folder), "--out", str(d / "calib.yaml"), "--html",
            str(d / "report.html")]


SAFETY_CASES: list[Case] = [
    Case("out_is_imu", "outputs", "--out names the --imu file", _out_is_imu,
         Expect(2, ("--out", "is the input --imu", "another path"))),
    Case("out_is_html", "outputs", "--out and --html name one file", _out_is_html,
         Expect(2, ("--html", "is also --out", "its own path"))),
    Case("export_onto_itself", "outputs", "export --out names its own calibration",
         _export_onto_itself, Expect(2, ("--out", "is the input CALIBRATION"))),
    Case("groundtruth_sidecar_onto_calibration", "outputs",
         "groundtruth --out calib.csv beside calib.yaml (the sidecar's name) as --calibration",
         _groundtruth_sidecar_onto_calibration,
         Expect(2, ("--out (its sidecar)", "is the input --calibration"))),
    Case("prior_translation_1e308", "priors", "a --prior whose lever arm is 1e308 m",
         _with_prior(**{"T_marker_imu.translation": [1e308, 0.0, 0.0]}),
         Expect(2, ("prior.yaml", "T_marker_imu.translation", "1e+308 m"))),
    Case("prior_negative_sigma", "priors", "a --prior with negative sigmas",
         _with_prior(**{"sigma.rotation": [-1e-3, 1e-3, 1e-3]}),
         Expect(2, ("prior.yaml", "sigma.rotation", "positive"))),
    Case("prior_conflicting", "priors", "a --prior whose lever arm is 50 mm off (sigma 0.2 mm)",
         _prior_moved, Expect(2, ("prior.yaml", "p_MI", "from what this session's data say",
                                  "--trust-prior"))),
    Case("prior_consistent", "priors", "a --prior of the same rig (its truth, 1 mm sigma)",
         _with_prior(), Expect(0, notes=("priors used from", "agrees"))),
    Case("noise_1e30", "option files", "a --noise file with a density of 1e30",
         _with_option_file("--noise", "gyroscope_noise_density: 1.0e+30\n"),
         Expect(2, ("opt.yaml", "gyroscope_noise_density", "--gyro-noise"))),
    Case("plausible_nan", "option files", "--plausible with accel_bias: .nan",
         _with_option_file("--plausible", "accel_bias: .nan\n"),
         Expect(2, ("opt.yaml", "'accel_bias' is nan", "finite positive"))),
    Case("manifest_4301_digits", "batch", "a manifest value of 4301 digits",
         _batch(lambda d: _one_session(d, extra="    window: " + "1" * 4301 + "\n")),
         Expect(2, ("manifest.yaml", "sessions[0].window", "4301 digits"))),
    Case("manifest_impossible_date", "batch", "a manifest date 2024-02-30",
         _batch(lambda d: _one_session(d).replace("2024-03-01", "2024-02-30")),
         Expect(2, ("manifest.yaml", "sessions[0].date", "2024-02-30 does not exist"))),
    Case("manifest_alias_bomb", "batch", "a manifest of nested aliases (a billion laughs)",
         _batch(_alias_bomb), Expect(2, ("manifest.yaml", "aliases", "expand to"))),
    Case("batch_id_batch_yaml", "batch", "a session id: batch.yaml",
         _batch(lambda d: _one_session(d, "batch.yaml")),
         Expect(2, ("'batch.yaml'", "the batch's own OUT/batch.yaml"))),
    Case("scheduler_without_port", "batch", "batch --scheduler localhost (no port)",
         _batch(_one_session, "--engine", "dask", "--scheduler", "localhost"),
         Expect(2, ("--scheduler localhost", "missing port", "tcp://HOST:PORT"))),
    Case("groundtruth_rate_100k", "option values", "groundtruth --rate 100000 (IMU at 200 Hz)",
         _groundtruth_rate, Expect(2, ("--rate 100000 Hz", "IMU's own 200 Hz"))),
    Case("export_nan_quaternion", "exports", "export to basalt of a NaN quaternion",
         _export_with("basalt", **{"T_marker_imu.rotation_wxyz": [float("nan"), 0.0, 0.0,
                                                                   0.0]}),
         Expect(2, ("T_marker_imu.rotation_wxyz is [nan", "not a finite number"))),
    Case("export_zero_quaternion", "exports", "export to px4 of a zero quaternion",
         _export_with("px4", **{"T_marker_imu.rotation_wxyz": [0.0, 0.0, 0.0, 0.0]}),
         Expect(2, ("T_marker_imu.rotation_wxyz", "zero length"))),
    Case("html_name_not_utf8", "outputs", "calibrate --html of a folder named with byte 0xff",
         _name_not_utf8, Expect(0)),
]

ALL_CASES += SAFETY_CASES

# --- inputs: formats, the crop before the checks, causes named ---------------------------------

def _crazyflie(cut: int = 0, poses: bool = True) -> Callable[[Path], list[str]]:
    """The clean session as a Crazyflie uSD log (deg/s, g; one file), optionally cut short by
    ``cut`` bytes or without its pose events."""
    from usd_logs import session_log

    def build(d: Path) -> list[str]:
        data = session_log(clean().imu, clean().mocap if poses else None)
        log = d / "log00"
        log.write_bytes(data[:len(data) - cut])
        return ["--imu", str(log), "--mocap", str(log)]
    return build


def _euroc_files(imu_text: Callable[[str], str] | None = None, gz: bool = False,
                 mocap: MocapPoses | None = None, *extra: str) -> Callable[[Path], list[str]]:
    """The clean session as EuRoC files given with --imu/--mocap, the IMU file's text changed
    by ``imu_text`` or gzip-compressed."""
    import gzip

    def build(d: Path) -> list[str]:
        root = write_mav0(d, clean().imu, mocap or clean().mocap)
        imu = root / "imu0" / "data.csv"
        if imu_text is not None:
            imu.write_text(imu_text(imu.read_text()))
        if gz:
            imu = imu.with_suffix(".csv.gz")
            imu.write_bytes(gzip.compress((root / "imu0" / "data.csv").read_bytes()))
        return ["--imu", str(imu), "--mocap", str(root / "vicon0" / "data.csv"), *extra]
    return build


def _nan_row_at(seconds: float) -> Callable[[str], str]:
    def edit(text: str) -> str:
        lines = text.splitlines()
        k = 1 + int(seconds * 200)
        lines[k] = lines[k].rsplit(",", 1)[0] + ",nan"
        return "\n".join(lines) + "\n"
    return edit


def _clock_reset(text: str) -> str:
    """The IMU stamps from 15 s on moved back by 10 s (a logger whose clock restarted)."""
    lines = text.splitlines()
    for k in range(1 + 3000, len(lines)):
        t, rest = lines[k].split(",", 1)
        lines[k] = f"{int(t) - 10_000_000_000},{rest}"
    return "\n".join(lines) + "\n"


IO_CASES: list[Case] = [
    Case("crazyflie_log", "file layout", "a Crazyflie uSD log (deg/s, g, both streams)",
         _calibrate(_crazyflie()), Expect(0)),
    Case("crazyflie_truncated", "file layout", "a Crazyflie uSD log cut short",
         _calibrate(_crazyflie(cut=9)), Expect(2, ("truncated", "copy the log"))),
    Case("crazyflie_no_pose", "file layout", "a Crazyflie uSD log without estPose events",
         _calibrate(_crazyflie(poses=False)), Expect(2, ("no estPose", "--mocap-topic"))),
    Case("imu_gzip", "file layout", "the IMU CSV gzip-compressed",
         _calibrate(_euroc_files(gz=True)), Expect(2, ("gzip-compressed", "decompress"))),
    Case("imu_clock_reset", "time units", "the IMU clock jumps back by 10 s at 15 s",
         _calibrate(_euroc_files(_clock_reset)),
         Expect(2, ("clock resets", "split the file", "--end"))),
    Case("mocap_2hz", "option values", "mocap at 2 Hz",
         _calibrate(_euroc_files(None, False, clean().mocap.select(
             np.arange(len(clean().mocap)) % 50 == 0))),
         Expect(2, ("2 Hz", "at least 10 Hz"))),
    Case("bad_row_cropped_away", "option values", "a NaN IMU row at 25 s, --end 20",
         _calibrate(_euroc_files(_nan_row_at(25.0), False, None, "--end", "20")), Expect(0)),
    Case("columns_and_imu_columns", "option files", "--columns with --imu-columns",
         _calibrate(_euroc_files(None, False, None, "--columns", "t=0,gyro=1:4,accel=4:7",
                                 "--imu-columns", "t=0,gyro=1:4,accel=4:7")),
         Expect(2, ("--columns and --imu-columns both given",))),
]

ALL_CASES += IO_CASES
