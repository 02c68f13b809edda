"""A corpus of bad and tricky inputs, as a new user would make them: mostly a clean 30 s
simulated session corrupted one way at a time, run through the CLI in-process.

Every case says what the user did, the command, and what must happen: a refusal (exit code and
the words that name the mistake) or an answer (exit 0) that agrees with the simulator's truth
within its own sigmas, with what the motion cannot determine reported as unobservable (null),
never as a number. :func:`run_case` gives the verdict; ``tests/test_refusals.py`` runs them
and ``scripts/refusal_table.py`` writes the table of ``docs/refusals.md``.
"""

from __future__ import annotations

import contextlib
import io
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np
import yaml

from mocap_calib.cli.main import main
from mocap_calib.core.model import so3
from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.io.formats.euroc import IMU_HEADER, POSE_HEADER, write_euroc_imu, write_mav0
from mocap_calib.io.tables import write_table
from mocap_calib.sim.flight import SimConfig, SimulatedSession, simulate_flight

DURATION = 30.0
SEED = 7


@cache
def session(seed: int = SEED, motion: str = "flight", duration: float = DURATION,
            effects: tuple[tuple[str, float], ...] = ()) -> SimulatedSession:
    eff = {k: [v] for k, v in effects}
    return simulate_flight(SimConfig(seed=seed, duration=duration, motion=motion, effects=eff))


def clean() -> SimulatedSession:
    return session()


@dataclass(frozen=True)
class Expect:
    """What must happen: ``code`` and, for refusals, words its one line must hold (all of
    them, case-insensitive); for exit 0 the result is checked against the truth."""

    code: int
    words: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()  # words a note of the result must hold (exit 0)
    max_seconds: float | None = None


@dataclass(frozen=True)
class Case:
    name: str
    kind: str  # its group in docs/refusals.md's table
    what: str  # what the user did
    build: Callable[[Path], list[str]]  # writes the inputs, returns the command line
    expect: Expect
    slow: bool = False


@dataclass
class Verdict:
    case: Case
    code: int
    line: str  # the last stderr line (the refusal) or the result's summary
    seconds: float
    problems: list[str] = field(default_factory=list)
    command: str = ""

    @property
    def ok(self) -> bool:
        return not self.problems


# --- corruptions ---------------------------------------------------------------------------

def _imu(s: SimulatedSession, gyro=None, accel=None, t=None) -> ImuSamples:
    i = s.imu
    return ImuSamples(i.t if t is None else t, i.gyro if gyro is None else gyro,
                      i.accel if accel is None else accel, i.time_origin_ns, i.source)


def _mocap(s: SimulatedSession, quat=None, pos=None) -> MocapPoses:
    m = s.mocap
    return MocapPoses(m.t, m.quat_wxyz if quat is None else quat,
                      m.position if pos is None else pos, m.time_origin_ns, m.source)


def mav0(imu: ImuSamples | None = None, mocap: MocapPoses | None = None,
         *extra: str) -> Callable[[Path], list[str]]:
    def build(d: Path) -> list[str]:
        write_mav0(d, imu or clean().imu, mocap or clean().mocap)
        return [str(d), *extra]
    return build


def _calibrate(build: Callable[[Path], list[str]]) -> Callable[[Path], list[str]]:
    def b(d: Path) -> list[str]:
        return ["calibrate", *build(d), "--out", str(d / "calib.yaml")]
    return b


def _diagnose(build: Callable[[Path], list[str]]) -> Callable[[Path], list[str]]:
    def b(d: Path) -> list[str]:
        return ["diagnose", *build(d), "--out", str(d / "report.yaml")]
    return b


def _flip_axis(s: SimulatedSession, axis: int) -> ImuSamples:
    g, a = s.imu.gyro.copy(), s.imu.accel.copy()
    g[:, axis] *= -1
    a[:, axis] *= -1
    return _imu(s, g, a)


def _inverse_pose(s: SimulatedSession) -> MocapPoses:
    R = s.mocap.rotation
    p = -np.einsum("nji,nj->ni", R, s.mocap.position)
    return _mocap(s, so3.rotmat_to_quat(np.transpose(R, (0, 2, 1))), p)


def _conjugate(s: SimulatedSession) -> MocapPoses:
    return _mocap(s, s.mocap.quat_wxyz * np.array([1.0, -1, -1, -1]))


def _xyzw(s: SimulatedSession) -> MocapPoses:
    # Written in the file's w,x,y,z columns in x,y,z,w order; read as wxyz.
    return _mocap(s, s.mocap.quat_wxyz[:, [1, 2, 3, 0]])


def generic_csv(d: Path, s: SimulatedSession, *, t_scale: float = 1.0, pos_scale: float = 1.0,
                gyro_scale: float = 1.0, quat_cols: tuple[int, ...] = (0, 1, 2, 3)) -> Path:
    """One file with both streams (BROAD-like), times in s (x ``t_scale``), the mocap
    interpolated onto the IMU stamps."""
    i, m = s.imu, s.mocap
    R = so3.quat_to_rotmat(s.mocap.quat_wxyz)
    idx = np.clip(np.searchsorted(m.t, i.t), 0, len(m.t) - 1)
    q = so3.rotmat_to_quat(R[idx])[:, list(quat_cols)]
    p = m.position[idx] * pos_scale
    t = i.t * t_scale
    path = d / "session.csv"
    write_table(path, "t,gx,gy,gz,ax,ay,az,qw,qx,qy,qz,px,py,pz",
                [t, *(i.gyro * gyro_scale).T, *i.accel.T, *q.T, *p.T])
    return path


def _generic(pos_scale: float = 1.0, gyro_scale: float = 1.0, t_scale: float = 1.0,
             *extra: str, s: Callable[[], SimulatedSession] = clean,
             columns: str = "t=0,gyro=1:4,accel=4:7,quat=7:11,pos=11:14"
             ) -> Callable[[Path], list[str]]:
    def build(d: Path) -> list[str]:
        path = generic_csv(d, s(), pos_scale=pos_scale, gyro_scale=gyro_scale, t_scale=t_scale)
        return ["--imu", str(path), "--mocap", str(path), "--columns", columns, *extra]
    return build


def _halves() -> Callable[[Path], list[str]]:
    s, half = clean(), DURATION / 2
    return mav0(s.imu.select(s.imu.t < half), s.mocap.select(s.mocap.t >= half))


def _clip(s: SimulatedSession, gyro_max: float, accel_max: float) -> ImuSamples:
    return _imu(s, np.clip(s.imu.gyro, -gyro_max, gyro_max),
                np.clip(s.imu.accel, -accel_max, accel_max))


def _frozen_mocap(s: SimulatedSession, t0: float, seconds: float) -> MocapPoses:
    m = s.mocap
    q, p = m.quat_wxyz.copy(), m.position.copy()
    k = np.flatnonzero((m.t >= t0) & (m.t < t0 + seconds))
    q[k] = q[k[0] - 1]
    p[k] = p[k[0] - 1]
    return _mocap(s, q, p)


def _frozen_imu(s: SimulatedSession, t0: float, seconds: float) -> ImuSamples:
    g, a = s.imu.gyro.copy(), s.imu.accel.copy()
    k = np.flatnonzero((s.imu.t >= t0) & (s.imu.t < t0 + seconds))
    g[k] = g[k[0] - 1]
    a[k] = a[k[0] - 1]
    return _imu(s, g, a)


def _dead(s: SimulatedSession, sensor: str, axes: tuple[int, ...] = (0, 1, 2)) -> ImuSamples:
    g, a = s.imu.gyro.copy(), s.imu.accel.copy()
    (g if sensor == "gyro" else a)[:, list(axes)] = 0.0
    return _imu(s, g, a)


def _mocap_stamps_us(d: Path) -> list[str]:
    s = clean()
    write_mav0(d, s.imu, s.mocap)
    us = s.mocap.stamps_ns() // 1000
    p, q = s.mocap.position, s.mocap.quat_wxyz
    write_table(d / "mav0" / "vicon0" / "data.csv", POSE_HEADER, [us, *p.T, *q.T])
    return [str(d)]


def _imu_stamps_seconds(d: Path) -> list[str]:
    s = clean()
    write_mav0(d, s.imu, s.mocap)
    sec = [f"{x:.6f}" for x in s.imu.stamps_ns() * 1e-9]
    write_table(d / "mav0" / "imu0" / "data.csv", IMU_HEADER, [sec, *s.imu.gyro.T,
                                                                *s.imu.accel.T])
    return [str(d)]


def _long_stamps(d: Path) -> list[str]:
    s = clean()
    write_mav0(d, s.imu, s.mocap)
    f = d / "mav0" / "imu0" / "data.csv"
    lines = f.read_text().splitlines()
    lines[5] = "9" * 5000 + lines[5][lines[5].index(","):]
    f.write_text("\n".join(lines) + "\n")
    return [str(d)]


def _with_file(content: bytes, option: str, name: str = "opt.yaml"
               ) -> Callable[[Path], list[str]]:
    def build(d: Path) -> list[str]:
        write_mav0(d, clean().imu, clean().mocap)
        (d / name).write_bytes(content)
        return [str(d), option, str(d / name)]
    return build


BINARY = bytes(range(256)) * 8


def _drift_with(content: bytes) -> Callable[[Path], list[str]]:
    def build(d: Path) -> list[str]:
        write_euroc_imu(d / "imu.csv", clean().imu)
        (d / "calib.yaml").write_bytes(content)
        return ["drift", "--imu", str(d / "imu.csv"), "--calibration", str(d / "calib.yaml"),
                "--segment-start", "5", "--segment-end", "15", "--out", str(d / "drift.yaml")]
    return build


def _imu_only(cmd: str, imu: Callable[[], ImuSamples], *extra: str
              ) -> Callable[[Path], list[str]]:
    def build(d: Path) -> list[str]:
        write_euroc_imu(d / "imu.csv", imu())
        return [cmd, "--imu", str(d / "imu.csv"), "--out", str(d / "out.yaml"), *extra]
    return build


def _static_log(kind: str) -> ImuSamples:
    from mocap_calib.sim.static import simulate_static

    imu, _ = simulate_static(seed=3, duration_s=600.0, rate_hz=100.0)
    g, a = imu.gyro.copy(), imu.accel.copy()
    if kind == "dead accel":
        a[:] = 0.0
    elif kind == "frozen":
        k = slice(20000, 20300)
        g[k], a[k] = g[19999], a[19999]
    return ImuSamples(imu.t, g, a, imu.time_origin_ns, imu.source)


def _multipos_log(kind: str) -> ImuSamples:
    from mocap_calib.sim.multipos import simulate_multipos

    imu, _ = simulate_multipos(seed=2)
    g, a = imu.gyro.copy(), imu.accel.copy()
    if kind == "dead gyro":
        g[:] = 0.0
    return ImuSamples(imu.t, g, a, imu.time_origin_ns, imu.source)


def _prior_yaml() -> bytes:
    return yaml.safe_dump({"kind": "calibration", "version": 1, "gyro_bias": "fast",
                           "T_marker_imu": {"rotation_wxyz": [1, 0]}}).encode()


CASES: list[Case] = [
    # --- the clean session and harmless variations: right answers ------------------------
    Case("clean", "clean", "a clean 30 s session", _calibrate(mav0()), Expect(0)),
    Case("clean_offset", "clean", "a clean session with a 20 ms clock offset",
         _calibrate(lambda d: mav0(session(effects=(("time_offset", 0.02),)).imu,
                                   session(effects=(("time_offset", 0.02),)).mocap)(d)),
         Expect(0)),
    # --- conventions: exit 2 naming the convention ----------------------------------------
    Case("accel_sign", "conventions", "accelerometer sign flipped",
         _calibrate(lambda d: mav0(_imu(clean(), accel=-clean().imu.accel))(d)),
         Expect(2, ("accelerometer", "sign"))),
    Case("imu_y_flipped", "conventions", "IMU y axis flipped (left-handed IMU frame)",
         _calibrate(lambda d: mav0(_flip_axis(clean(), 1))(d)),
         Expect(2, ("y axis", "left-handed"))),
    Case("inverse_pose", "conventions", "mocap gives T_MW (inverse pose) instead of T_WM",
         _calibrate(lambda d: mav0(None, _inverse_pose(clean()))(d)),
         Expect(2, ("inverse", "T_MW"))),
    Case("jpl_quaternions", "conventions", "JPL (conjugated) quaternions",
         _calibrate(lambda d: mav0(None, _conjugate(clean()))(d)),
         Expect(2, ("conjugate", "JPL"))),
    Case("xyzw_quaternions", "conventions", "xyzw quaternions without --quat-order",
         _calibrate(lambda d: mav0(None, _xyzw(clean()))(d)),
         Expect(2, ("xyzw", "--quat-order xyzw"))),
    Case("position_cm", "conventions", "mocap positions in cm, read as m",
         _calibrate(_generic(pos_scale=100.0)), Expect(2, ("cm",))),
    Case("position_cm_as_mm", "conventions",
         "mocap positions in cm, passed as --position-unit mm",
         _calibrate(_generic(100.0, 1.0, 1.0, "--position-unit", "mm")),
         Expect(2, ("--position-unit cm",))),
    Case("position_mm_as_cm", "conventions",
         "mocap positions in mm, passed as --position-unit cm",
         _calibrate(_generic(1000.0, 1.0, 1.0, "--position-unit", "cm")),
         Expect(2, ("--position-unit mm",))),
    Case("gyro_deg_slow", "conventions", "gyro in deg/s on a slow session (passes the reader)",
         _calibrate(_generic(1.0, float(np.degrees(1.0)), 1.0,
                             s=lambda: session(motion="slow"))),
         Expect(2, ("--gyro-unit deg/s",))),
    # --- mismatched streams: exit 3 -------------------------------------------------------
    Case("two_recordings", "mismatched", "IMU and mocap from two different recordings",
         _calibrate(lambda d: mav0(clean().imu, session(seed=8).mocap)(d)),
         Expect(3, ("same",))),
    Case("disjoint_halves", "mismatched", "IMU and mocap cover disjoint halves of one flight",
         _calibrate(lambda d: _halves()(d)), Expect(3, ("overlap",))),
    # --- degenerate motion: unobservable, never wrong -------------------------------------
    Case("turntable", "degenerate", "rotation about one vertical axis only (turntable)",
         _calibrate(lambda d: mav0(session(motion="turntable").imu,
                                   session(motion="turntable").mocap)(d)), Expect(0)),
    Case("planar", "degenerate", "planar ground-robot motion (yaw only)",
         _calibrate(lambda d: mav0(session(motion="planar").imu,
                                   session(motion="planar").mocap)(d)), Expect(0)),
    Case("slow", "degenerate", "slow, low-excitation 3D motion",
         _calibrate(lambda d: mav0(session(motion="slow").imu,
                                   session(motion="slow").mocap)(d)), Expect(0)),
    # --- sensor faults ---------------------------------------------------------------------
    Case("saturated", "faults",
         "gyro clipped at 1.6 rad/s and accel at 13 m/s^2 (18 % of the rows)",
         _calibrate(lambda d: mav0(_clip(clean(), 1.6, 13.0))(d)),
         Expect(0, notes=("saturat",))),
    Case("accel_dead", "faults", "accelerometer dead (all zeros)",
         _calibrate(lambda d: mav0(_dead(clean(), "accel"))(d)),
         Expect(2, ("accelerometer", "dead"))),
    Case("gyro_z_dead", "faults", "one gyro channel dead (z reads 0)",
         _calibrate(lambda d: mav0(_dead(clean(), "gyro", (2,)))(d)),
         Expect(2, ("gyro z", "dead"))),
    Case("mocap_frozen", "faults", "mocap frozen for 3 s (last pose repeated)",
         _calibrate(lambda d: mav0(None, _frozen_mocap(clean(), 12.0, 3.0))(d)),
         Expect(0, notes=("frozen",))),
    Case("imu_frozen", "faults", "IMU frozen for 1 s (last sample repeated)",
         _calibrate(lambda d: mav0(_frozen_imu(clean(), 17.0, 1.0))(d)),
         Expect(0, notes=("frozen",))),
    Case("mocap_dead", "faults", "mocap frozen for the whole session",
         _calibrate(lambda d: mav0(None, _frozen_mocap(clean(), 0.01, DURATION))(d)),
         Expect(2, ("mocap", "frozen"))),
    # --- option files and maps: one line, exit 2 ------------------------------------------
    Case("noise_binary", "option files", "a binary file as --noise",
         _calibrate(_with_file(BINARY, "--noise")), Expect(2, ("binary",))),
    Case("noise_empty", "option files", "an empty --noise file",
         _calibrate(_with_file(b"", "--noise")), Expect(2, ("empty",))),
    Case("noise_list", "option files", "a --noise file holding a YAML list",
         _calibrate(_with_file(b"- 1\n- 2\n", "--noise")), Expect(2, ("mapping",))),
    Case("prior_binary", "option files", "a binary file as --prior",
         _calibrate(_with_file(BINARY, "--prior")), Expect(2, ("binary",))),
    Case("prior_malformed", "option files", "a --prior result with wrong types",
         _calibrate(_with_file(_prior_yaml(), "--prior")), Expect(2, ("accel_bias",))),
    Case("calibration_binary", "option files", "a binary file as drift's --calibration",
         _drift_with(BINARY), Expect(2, ("binary",))),
    Case("columns_twice", "option files", "a --columns map that uses a column twice",
         _calibrate(_generic(1.0, 1.0, 1.0,
                             columns="t=0,gyro=1:4,accel=1:4,quat=7:11,pos=11:14")),
         Expect(2, ("--columns", "twice"))),
    Case("columns_reversed", "option files", "a --columns range written backwards",
         _calibrate(_generic(1.0, 1.0, 1.0,
                             columns="t=0,gyro=4:1,accel=4:7,quat=7:11,pos=11:14")),
         Expect(2, ("--columns",))),
    # --- time units: named with the flag --------------------------------------------------
    Case("imu_stamps_s", "time units", "IMU stamps in s where EuRoC's ns are expected",
         _calibrate(_imu_stamps_seconds), Expect(2, ("seconds", "--time-unit"))),
    Case("mocap_stamps_us", "time units", "mocap stamps in us in an EuRoC folder",
         _calibrate(_mocap_stamps_us), Expect(2, ("us",))),
    Case("stamps_5000_digits", "time units", "a timestamp of 5000 digits",
         _calibrate(_long_stamps), Expect(2, ("5000 digits",))),
    Case("stamps_ms_as_s", "time units", "generic CSV in ms read as s",
         _calibrate(_generic(1.0, 1.0, 1000.0)), Expect(2, ("ms", "--time-unit ms"))),
    Case("stamps_ns_as_s", "time units", "generic CSV in ns read as s",
         _calibrate(_generic(1.0, 1.0, 1e9)), Expect(2, ("ns", "--time-unit ns"))),
    # --- the other commands ----------------------------------------------------------------
    Case("diagnose_two_recordings", "other commands", "diagnose on two different recordings",
         _diagnose(lambda d: mav0(clean().imu, session(seed=8).mocap)(d)),
         Expect(3, ("same",), max_seconds=20.0)),
    Case("diagnose_gyro_deg_slow", "other commands",
         "diagnose on a slow session with the gyro in deg/s",
         _diagnose(_generic(1.0, float(np.degrees(1.0)), 1.0,
                            s=lambda: session(motion="slow"))),
         Expect(2, ("--gyro-unit deg/s",), max_seconds=20.0)),
    Case("diagnose_accel_dead", "other commands", "diagnose with a dead accelerometer",
         _diagnose(lambda d: mav0(_dead(clean(), "accel"))(d)),
         Expect(2, ("accelerometer", "dead"))),
    Case("allan_dead_accel", "other commands", "allan on a log whose accelerometer is dead",
         _imu_only("allan", lambda: _static_log("dead accel")),
         Expect(2, ("accelerometer", "dead"))),
    Case("allan_frozen", "other commands", "allan on a log frozen for 3 s",
         _imu_only("allan", lambda: _static_log("frozen")), Expect(2, ("frozen",))),
    Case("multipos_dead_gyro", "other commands", "multipos with a dead gyro",
         _imu_only("multipos", lambda: _multipos_log("dead gyro")),
         Expect(2, ("gyro", "dead"))),
]


# --- running and judging --------------------------------------------------------------------

def run_cli(argv: list[str]) -> tuple[int, str, str, float]:
    out, err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue(), time.perf_counter() - t0


def _truth_of(case: Case) -> dict:
    if case.name == "clean_offset":
        return session(effects=(("time_offset", 0.02),)).truth
    motion = case.name if case.name in ("turntable", "planar", "slow") else "flight"
    return session(motion=motion).truth


#: Largest error accepted from a number the tool prints (beyond its own 5 sigma, these
#: would be useless anyway): R_MI (deg), p_MI (m), t_d (s), biases.
_USEFUL = {"rotation": 2.0, "translation": 0.05, "time_offset": 0.005,
           "gyro_bias": 0.01, "accel_bias": 0.1}


def check_result(path: Path, truth: dict) -> list[str]:
    """Problems of an exit-0 result against the truth: a number more than 5 sigma (and more
    than a floor) off, or useless (beyond :data:`_USEFUL`)."""
    d = yaml.safe_load(path.read_text())
    sig = d.get("sigma") or {}
    problems = []

    def judge(name: str, err: np.ndarray, sigma, floor: float) -> None:
        s = np.atleast_1d(np.asarray(sigma if sigma is not None else np.inf, dtype=float))
        if np.any(np.abs(err) > 5 * s + floor):
            problems.append(f"{name} off by {np.round(err, 5).tolist()} (sigma "
                            f"{np.round(s, 5).tolist()})")
        elif np.max(np.abs(err)) > _USEFUL[name]:
            problems.append(f"{name} off by {np.round(err, 5).tolist()}: useless, should be "
                            "reported unobservable")

    tq = truth["T_marker_imu"]
    if d["T_marker_imu"]["rotation_wxyz"] is not None:
        R = so3.quat_to_rotmat(np.asarray(d["T_marker_imu"]["rotation_wxyz"]))
        Rt = so3.quat_to_rotmat(np.asarray(tq["rotation_wxyz"]))
        judge("rotation", np.degrees(so3.log(Rt.T @ R)),
              None if sig.get("rotation") is None else np.degrees(sig["rotation"]), 0.02)
    if d["T_marker_imu"]["translation"] is not None:
        judge("translation", np.asarray(d["T_marker_imu"]["translation"])
              - np.asarray(tq["translation"]), sig.get("translation"), 5e-4)
    if d.get("time_offset") is not None:
        judge("time_offset", np.asarray([d["time_offset"] - truth["time_offset"]]),
              sig.get("time_offset"), 2e-4)
    for b in ("gyro_bias", "accel_bias"):
        if d.get(b) is not None:
            judge(b, np.asarray(d[b]) - np.asarray(truth[b]), sig.get(b), 0.0)
    return problems


def run_case(case: Case, d: Path) -> Verdict:
    d.mkdir(parents=True, exist_ok=True)
    argv = case.build(d)
    code, out, err, seconds = run_cli(argv)
    lines = [x for x in err.splitlines() if x.strip()]
    last = lines[-1] if lines else ""
    v = Verdict(case, code, last, seconds, command=argv[0])
    e = case.expect
    if "Traceback" in out + err or code == 70:
        v.problems.append(f"internal error: {last}")
    if code != e.code:
        v.problems.append(f"exit {code}, expected {e.code}: {last}")
    if e.max_seconds is not None and seconds > e.max_seconds:
        v.problems.append(f"took {seconds:.1f} s (limit {e.max_seconds:g} s)")
    if code != 0:
        if not last.startswith("error:"):
            v.problems.append(f"the refusal is not one 'error:' line: {last!r}")
        missing = [w for w in e.words if w.lower() not in last.lower()]
        if missing:
            v.problems.append(f"the refusal does not name {missing}: {last}")
        return v
    if argv[0] == "calibrate":
        res = d / "calib.yaml"
        data = yaml.safe_load(res.read_text())
        notes = " ".join(data.get("notes") or [])
        unob = list(data.get("unobservable") or {})
        faults = [n for n in data.get("notes") or [] if "left out" in n]
        v.line = "; ".join(["numbers checked against the truth",
                            *([f"null (unobservable): {', '.join(unob)}"] if unob else []),
                            *[f"note: {n}" for n in faults]])
        v.problems += check_result(res, _truth_of(case))
        missing = [w for w in e.notes if w.lower() not in notes.lower()]
        if missing:
            v.problems.append(f"no note naming {missing}")
    return v
