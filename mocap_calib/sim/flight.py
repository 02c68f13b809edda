"""Simulated mocap flights with known truth.

The IMU samples are computed exactly from the trajectory's analytic derivatives through the
measurement model of ``docs/conventions.md``; the mocap poses are the exact marker poses plus
noise. Effects beyond the base model are injected by their canonical names. One seeded
generator drives every random draw, so the same configuration gives the same bytes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import CANONICAL_EFFECTS, EFFECTS
from mocap_calib.core.model.types import ImuSamples, MocapPoses, NoiseModel
from mocap_calib.core.model.versioned import header
from mocap_calib.core.policy import GRAVITY
from mocap_calib.errors import InputError
from mocap_calib.sim.faults import imu_gaps
from mocap_calib.sim.motions import MOTIONS, motion_trajectory
from mocap_calib.sim.trajectory import (
    Trajectory,
    periodic_trajectory,
    random_trajectory,
    with_fast_motion,
)

Array = NDArray[np.float64]

#: Effects only the simulator knows: faults of the streams, not of the IMU model.
MOCAP_FAULTS = ("mocap_dropouts", "mocap_outliers")
#: IMU logging faults, as flight controllers' logs have them: dropped samples and stalls.
IMU_FAULTS = ("imu_dropouts", "imu_stalls")
SIM_FAULTS = (*MOCAP_FAULTS, *IMU_FAULTS)

#: What a bare ``--effect NAME`` injects: a realistic magnitude (see ``effect_help``).
DEFAULT_MAGNITUDE: dict[str, float] = {
    "time_offset": 0.005,
    "gyro_scale_misalignment": 0.003,
    "accel_scale_misalignment": 0.003,
    "gyro_g_sensitivity": 3e-4,
    "gyro_bias_drift": 2e-5,
    "accel_bias_drift": 2e-3,
    "gravity_magnitude": 9.79,
    "clock_drift": 1e-4,
    "accel_delay": 0.004,
    "accel_size_effect": 0.01,
    "mocap_dropouts": 5,
    "mocap_outliers": 5,
    "imu_dropouts": 30,
    "imu_stalls": 0.5,
}

EFFECT_HELP: dict[str, str] = {
    "time_offset": "t_d in s (IMU stamp t was measured at mocap time t + t_d)",
    "gyro_scale_misalignment": "std of the entries of M_g - I, or 9 values row-major",
    "accel_scale_misalignment": "std of the entries of the lower-triangular M_a - I, or 9 values",
    "gyro_g_sensitivity": "std of the entries of G in rad/s per m/s^2, or 9 values",
    "gyro_bias_drift": "trend magnitude in rad/s per s, or 3 values",
    "accel_bias_drift": "trend magnitude in m/s^2 per s, or 3 values",
    "gravity_magnitude": f"true |g| in m/s^2 (the calibration assumes {GRAVITY})",
    "clock_drift": "IMU clock rate error s (1e-4 = 100 ppm); default: 100 ppm, random sign",
    "accel_delay": "how much the accelerometer lags the gyro, in s",
    "accel_size_effect": "distance of the y and z accelerometers from the x one (m, random "
    "directions), or 6 values r_y, r_z",
    "mocap_dropouts": "number of mocap gaps (0.05-1 s each, rows removed)",
    "mocap_outliers": "number of marker-swap events (1-4 samples jump by 3-10 cm, 5-30 deg)",
    "imu_dropouts": "number of IMU gaps of 12-161 ms (logger buffer overruns, as PX4 logs have "
    "them), plus one after the first sample",
    "imu_stalls": "lengths of IMU stalls in s (1-5 values, e.g. 0.5,3)",
}


def parse_effect(spec: str) -> tuple[str, list[float] | None]:
    """Parse ``NAME`` or ``NAME=VALUE`` or ``NAME=v1,v2,...``."""
    name, _, value = spec.partition("=")
    name = name.strip()
    known = (*CANONICAL_EFFECTS, *SIM_FAULTS)
    if name not in known:
        raise InputError(f"unknown effect '{name}'; choose one of: {', '.join(known)}")
    if not value.strip():
        return name, None
    try:
        values = [float(v) for v in value.split(",")]
    except ValueError:
        raise InputError(f"effect '{spec}': value must be a number or comma-separated numbers, "
                         f"e.g. {name}=0.01") from None
    if not all(np.isfinite(values)):
        raise InputError(f"effect '{spec}': value must be finite")
    allowed = _VALUE_COUNTS.get(name, (1,))
    if len(values) not in allowed:
        counts = " or ".join(str(c) for c in allowed)
        raise InputError(f"effect '{spec}': give {counts} value(s) ({EFFECT_HELP[name]})")
    if name in _NON_NEGATIVE and len(values) == 1 and values[0] < 0:
        raise InputError(f"effect '{spec}': the magnitude must not be negative")
    if name in ("mocap_dropouts", "mocap_outliers", "imu_dropouts") and (
            values[0] != int(values[0]) or values[0] > 1000):
        raise InputError(f"effect '{spec}': give a whole number of events between 0 and 1000")
    return name, values


#: How many values an effect accepts (a magnitude, or the full matrix / vector).
_VALUE_COUNTS: dict[str, tuple[int, ...]] = {
    "gyro_scale_misalignment": (1, 9),
    "accel_scale_misalignment": (1, 9),
    "gyro_g_sensitivity": (1, 9),
    "gyro_bias_drift": (1, 3),
    "accel_bias_drift": (1, 3),
    "accel_size_effect": (1, 6),
    "imu_stalls": (1, 2, 3, 4, 5),
}
#: Effects whose single value is a magnitude (std or count), so it cannot be negative.
_NON_NEGATIVE = ("gyro_scale_misalignment", "accel_scale_misalignment", "gyro_g_sensitivity",
                 "gyro_bias_drift", "accel_bias_drift", "gravity_magnitude", "accel_size_effect",
                 *MOCAP_FAULTS, "imu_dropouts")


@dataclass(frozen=True)
class SimConfig:
    """What to simulate. ``effects`` maps a canonical name to its value(s) or None (default)."""

    seed: int = 0
    duration: float = 90.0
    imu_rate: float = 200.0
    mocap_rate: float = 100.0
    gravity: float = GRAVITY
    noise: NoiseModel = field(default_factory=NoiseModel)
    effects: dict[str, list[float] | None] = field(default_factory=dict)
    imu_time_origin_ns: int = 1_600_000_000_000_000_000
    mocap_time_origin_ns: int = 1_600_000_000_000_000_000
    aggressiveness: float = 1.0
    rig_seed: int | None = None  # draw T_MI and the room's tilt from this seed (a fixed rig)
    mocap_noise_corr: float = 0.0  # s: AR(1) mocap noise with this time constant (0: white)
    periodic_motion_s: float = 0.0  # > 0: a flight repeating with this period (clock tests)
    motion: str = "flight"  # a key of sim.motions.MOTIONS (turntable, planar, slow, ...)
    max_motion_hz: float = 0.0  # > 0: the flight also moves at 1 Hz up to this (vibration-like)

    def validate(self) -> None:
        if self.motion not in MOTIONS:
            raise InputError(f"unknown --motion '{self.motion}'; choose one of: "
                             f"{', '.join(MOTIONS)}")
        if not self.duration > 1.0:
            raise InputError(f"--duration {self.duration}: must be more than 1 s")
        if self.duration > 4 * 3600:
            raise InputError(f"--duration {self.duration}: more than 4 h; simulate shorter "
                             "sessions")
        for name, rate in (("--imu-rate", self.imu_rate), ("--mocap-rate", self.mocap_rate)):
            if not 1.0 <= rate <= 10000.0:
                raise InputError(f"{name} {rate}: must be between 1 and 10000 Hz")
        if self.mocap_rate > self.imu_rate:
            raise InputError("--mocap-rate must not exceed --imu-rate")
        if not 0.0 <= self.mocap_noise_corr <= 10.0:
            raise InputError(f"--mocap-noise-corr {self.mocap_noise_corr}: give a time constant "
                             "in s between 0 (white) and 10, e.g. 0.3")
        if self.max_motion_hz and not 1.0 <= self.max_motion_hz <= min(20.0,
                                                                        self.mocap_rate / 5):
            raise InputError(f"--max-motion-hz {self.max_motion_hz:g}: give 0 (off) or 1 to "
                             f"{min(20.0, self.mocap_rate / 5):g} Hz (a fifth of the mocap "
                             "rate, at most 20)")
        if self.max_motion_hz and (self.motion != "flight" or self.periodic_motion_s > 0):
            raise InputError("--max-motion-hz: only for the random flight (motion 'flight', no "
                             "periodic_motion_s)")
        for name, values in self.effects.items():
            spec = name if values is None else f"{name}={','.join(repr(v) for v in values)}"
            parse_effect(spec)


@dataclass(frozen=True)
class SimulatedSession:
    """The simulated streams and the truth that generated them."""

    imu: ImuSamples
    mocap: MocapPoses
    truth: dict[str, Any]
    gyro_bias_true: Array  # (N, 3) per IMU sample
    accel_bias_true: Array  # (N, 3) per IMU sample


def _matrix_effect(rng: np.random.Generator, values: list[float] | None, default: float,
                   lower: bool = False) -> Array:
    if values is not None and len(values) == 9:
        m = np.asarray(values, dtype=float).reshape(3, 3)
    else:
        scale = default if values is None else values[0]
        m = rng.normal(0.0, scale, (3, 3))
    if lower:
        m = np.tril(m)
    return m


def _vector_effect(rng: np.random.Generator, values: list[float] | None, default: float) -> Array:
    if values is not None and len(values) == 3:
        return np.asarray(values, dtype=float)
    mag = default if values is None else values[0]
    d = rng.normal(size=3)
    return mag * d / np.linalg.norm(d)


def ar1(white: Array, tau_samples: float) -> Array:
    """AR(1) noise with the marginal sigma of ``white`` (rows: samples) and time constant
    ``tau_samples`` (in samples): n_k = a n_{k-1} + sqrt(1 - a^2) e_k, started stationary."""
    a = float(np.exp(-1.0 / tau_samples))
    out = lfilter([np.sqrt(1.0 - a * a)], [1.0, -a], white, axis=0)
    # Stationary start: the first sample carries the full variance.
    out += np.outer(a ** np.arange(len(white)), white[0] * (1.0 - np.sqrt(1.0 - a * a)))
    return out


def _random_rotation(rng: np.random.Generator) -> Array:
    q = rng.normal(size=4)
    return so3.quat_to_rotmat(q / np.linalg.norm(q))


@dataclass
class _Rig:
    """The rig's truth: IMU on the marker body, the room's tilt, the initial biases."""

    R_MI: Array
    p_MI: Array
    g_dir: Array
    bg0: Array
    ba0: Array


@dataclass
class _Truth:
    """The injected effects' true values (neutral when not injected)."""

    t_d: float = 0.0
    g: float = GRAVITY
    M_g: Array = field(default_factory=lambda: np.eye(3))
    M_a: Array = field(default_factory=lambda: np.eye(3))
    G: Array = field(default_factory=lambda: np.zeros((3, 3)))
    dbg: Array = field(default_factory=lambda: np.zeros(3))
    dba: Array = field(default_factory=lambda: np.zeros(3))
    drift: float = 0.0  # clock_drift s
    lag: float = 0.0  # accel_delay (s)
    r_size: Array = field(default_factory=lambda: np.zeros(6))  # r_y, r_z (m)


def simulate_flight(cfg: SimConfig) -> SimulatedSession:
    """Simulate one mocap session of a drone flight with known calibration.

    The IMU model is written out here on its own (not through ``core.model.imu_model``), so
    that the estimator is tested against a truth it did not compute.
    """
    cfg.validate()
    rng = np.random.default_rng(cfg.seed)
    effects = dict(cfg.effects)
    # Everything is drawn in a fixed order so the seed fixes everything.
    traj = random_trajectory(rng, aggressiveness=cfg.aggressiveness)
    if cfg.motion != "flight":
        # Another motion kind: its own generator, so the draws below stay the seed's.
        traj = motion_trajectory(cfg.motion, np.random.default_rng([cfg.seed, 17]),
                                 cfg.aggressiveness)
    if cfg.periodic_motion_s > 0:
        traj = periodic_trajectory(np.random.default_rng([cfg.seed, 1]), cfg.periodic_motion_s)
    if cfg.max_motion_hz > 0:
        # Its own generator, so every other draw stays the seed's.
        traj = with_fast_motion(traj, np.random.default_rng([cfg.seed, 29]), cfg.max_motion_hz)
    rig = _draw_rig(rng, cfg)
    tr = _draw_effects(rng, effects, cfg.gravity)
    t_imu, gyro, accel, b_g, b_a = _imu_samples(rng, cfg, traj, rig, tr)
    t_moc, R_meas, p_meas, keep, outlier_rows, gaps = _mocap_samples(rng, cfg, traj, rig,
                                                                     effects)
    # IMU logging faults last, with their own generator: every other draw stays the seed's.
    kept, dropped = imu_gaps(np.random.default_rng([cfg.seed, 41]), cfg.duration, t_imu,
                             effects, DEFAULT_MAGNITUDE)
    t_imu, gyro, accel, b_g, b_a = (x[kept] for x in (t_imu, gyro, accel, b_g, b_a))
    imu = ImuSamples(t_imu, gyro, accel, cfg.imu_time_origin_ns, "simulated imu")
    mocap = MocapPoses(t_moc[keep], so3.rotmat_to_quat(R_meas[keep]), p_meas[keep],
                       cfg.mocap_time_origin_ns, "simulated mocap")
    truth = _truth_file(cfg, effects, rig, tr, b_g, b_a)
    truth["simulation"].update({"mocap_outlier_rows": outlier_rows,
                                "mocap_gaps_start_length_s": gaps,
                                "mocap_rows_removed": int((~keep).sum()),
                                **({"imu_gaps_start_length_s": dropped} if dropped else {})})
    return SimulatedSession(imu, mocap, truth, b_g, b_a)


def _draw_rig(rng: np.random.Generator, cfg: SimConfig) -> _Rig:
    R_MI = _random_rotation(rng)
    p_MI = rng.uniform(-0.1, 0.1, 3)
    p_MI *= max(1.0, 0.04 / np.linalg.norm(p_MI))
    tilt_axis = np.array([*rng.normal(size=2), 0.0])
    tilt = so3.exp(np.radians(rng.uniform(0.5, 3.0)) * tilt_axis / np.linalg.norm(tilt_axis))
    g_dir = tilt @ np.array([0.0, 0.0, -1.0])
    bg0 = rng.uniform(-0.03, 0.03, 3)
    ba0 = rng.uniform(-0.15, 0.15, 3)
    # A fixed rig (same IMU on the same marker body, same room) across sessions: the drawn
    # values are replaced, the draws themselves still happen so the seed's sequence holds.
    if cfg.rig_seed is not None:
        r = np.random.default_rng(cfg.rig_seed)
        R_MI = _random_rotation(r)
        p_MI = r.uniform(-0.1, 0.1, 3)
        p_MI *= max(1.0, 0.04 / np.linalg.norm(p_MI))
        axis = np.array([*r.normal(size=2), 0.0])
        g_dir = so3.exp(np.radians(r.uniform(0.5, 3.0)) * axis / np.linalg.norm(axis)) @ np.array(
            [0.0, 0.0, -1.0])
    return _Rig(R_MI, p_MI, g_dir, bg0, ba0)


def _draw_effects(rng: np.random.Generator, effects: dict[str, list[float] | None],
                  gravity: float) -> _Truth:
    """The injected effects' values: given, or drawn at their default magnitude."""
    tr = _Truth(g=gravity)

    def value(name: str) -> list[float] | None:
        return effects[name]

    def scalar(name: str) -> float:
        v = value(name)
        return DEFAULT_MAGNITUDE[name] if v is None else v[0]

    if "time_offset" in effects:
        tr.t_d = scalar("time_offset")
    if "gravity_magnitude" in effects:
        tr.g = scalar("gravity_magnitude")
        if not 5.0 < tr.g < 15.0:
            raise InputError(f"gravity_magnitude={tr.g}: give |g| in m/s^2, e.g. 9.79")
    if "gyro_scale_misalignment" in effects:
        tr.M_g = np.eye(3) + _matrix_effect(rng, value("gyro_scale_misalignment"),
                                            DEFAULT_MAGNITUDE["gyro_scale_misalignment"])
    if "accel_scale_misalignment" in effects:
        tr.M_a = np.eye(3) + _matrix_effect(rng, value("accel_scale_misalignment"),
                                            DEFAULT_MAGNITUDE["accel_scale_misalignment"],
                                            lower=True)
    if "gyro_g_sensitivity" in effects:
        tr.G = _matrix_effect(rng, value("gyro_g_sensitivity"),
                              DEFAULT_MAGNITUDE["gyro_g_sensitivity"])
    if "gyro_bias_drift" in effects:
        tr.dbg = _vector_effect(rng, value("gyro_bias_drift"), DEFAULT_MAGNITUDE["gyro_bias_drift"])
    if "accel_bias_drift" in effects:
        tr.dba = _vector_effect(rng, value("accel_bias_drift"),
                                DEFAULT_MAGNITUDE["accel_bias_drift"])
    if "clock_drift" in effects:  # a rate error of either sign
        v = value("clock_drift")
        tr.drift = (DEFAULT_MAGNITUDE["clock_drift"] * rng.choice([-1.0, 1.0]) if v is None
                    else v[0])
    if "accel_delay" in effects:
        tr.lag = scalar("accel_delay")
    if "accel_size_effect" in effects:
        v = value("accel_size_effect")
        if v is not None and len(v) == 6:
            tr.r_size = np.asarray(v, dtype=float)
        else:
            mag = DEFAULT_MAGNITUDE["accel_size_effect"] if v is None else v[0]
            tr.r_size = np.r_[_vector_effect(rng, [mag], mag), _vector_effect(rng, [mag], mag)]
    return tr


def _imu_samples(rng: np.random.Generator, cfg: SimConfig, traj: Trajectory, rig: _Rig,
                 tr: _Truth) -> tuple[Array, Array, Array, Array, Array]:
    """IMU stamps on the IMU clock; a gyro sample stamped ``t`` was measured at mocap time
    ``t + t_d + s (t - t_mid)``, an accel sample ``lag`` earlier."""
    noise = cfg.noise
    n_imu = int(round(cfg.duration * cfg.imu_rate)) + 1
    t_imu = np.arange(n_imu) / cfg.imu_rate
    t_mid = 0.5 * (t_imu[0] + t_imu[-1])
    s_g = t_imu + tr.t_d + tr.drift * (t_imu - t_mid)
    s_a = s_g - tr.lag
    w_I = traj.angular_velocity_body(s_g)
    f_g = np.einsum("nji,nj->ni", traj.rotation(s_g), traj.acceleration(s_g) - tr.g * rig.g_dir)
    f_a = f_g if tr.lag == 0.0 else np.einsum(
        "nji,nj->ni", traj.rotation(s_a), traj.acceleration(s_a) - tr.g * rig.g_dir)
    if np.any(tr.r_size):
        # y and z accelerometers at r_y, r_z: e_i.(alpha x r_i + w x (w x r_i)).
        e = 1e-5
        w_a = traj.angular_velocity_body(s_a)
        w_rate = traj.angular_velocity_body
        alpha = (w_rate(s_a + e) - w_rate(s_a - e)) / (2 * e)
        f_a = f_a.copy()
        for i, r in ((1, tr.r_size[0:3]), (2, tr.r_size[3:6])):
            f_a[:, i] += (np.cross(alpha, r) + np.cross(w_a, np.cross(w_a, r)))[:, i]
    dt = 1.0 / cfg.imu_rate
    rw_g = np.cumsum(rng.normal(0.0, noise.gyroscope_random_walk * np.sqrt(dt), (n_imu, 3)), 0)
    rw_a = np.cumsum(rng.normal(0.0, noise.accelerometer_random_walk * np.sqrt(dt), (n_imu, 3)), 0)
    rw_g -= rw_g[0]
    rw_a -= rw_a[0]
    b_g = rig.bg0 + rw_g + np.outer(t_imu - t_mid, tr.dbg)
    b_a = rig.ba0 + rw_a + np.outer(t_imu - t_mid, tr.dba)
    n_g = rng.normal(0.0, noise.gyroscope_noise_density * np.sqrt(cfg.imu_rate), (n_imu, 3))
    n_a = rng.normal(0.0, noise.accelerometer_noise_density * np.sqrt(cfg.imu_rate), (n_imu, 3))
    gyro = w_I @ tr.M_g.T + f_g @ tr.G.T + b_g + n_g
    accel = f_a @ tr.M_a.T + b_a + n_a
    return t_imu, gyro, accel, b_g, b_a


def _mocap_samples(rng: np.random.Generator, cfg: SimConfig, traj: Trajectory, rig: _Rig,
                   effects: dict[str, list[float] | None]):
    """Marker poses ``T_WM = T_WI T_MI^-1`` at mocap stamps plus noise, marker swaps and
    dropouts: (stamps, R, p, rows kept, outlier rows, gaps)."""
    noise = cfg.noise
    n_moc = int(round(cfg.duration * cfg.mocap_rate)) + 1
    t_moc = np.arange(n_moc) / cfg.mocap_rate
    R_WM = traj.rotation(t_moc) @ rig.R_MI.T
    p_WM = traj.position(t_moc) - R_WM @ rig.p_MI
    n_rot = rng.normal(0.0, noise.mocap_rotation_sigma, (n_moc, 3))
    n_pos = rng.normal(0.0, noise.mocap_position_sigma, (n_moc, 3))
    if cfg.mocap_noise_corr > 0:
        n_rot = ar1(n_rot, cfg.mocap_noise_corr * cfg.mocap_rate)
        n_pos = ar1(n_pos, cfg.mocap_noise_corr * cfg.mocap_rate)
    R_meas = R_WM @ so3.exp(n_rot)
    p_meas = p_WM + n_pos
    outlier_rows: list[int] = []
    if "mocap_outliers" in effects:
        v = effects["mocap_outliers"]
        count = int(DEFAULT_MAGNITUDE["mocap_outliers"] if v is None else v[0])
        if count > (n_moc - 20) // 10:
            raise InputError(f"mocap_outliers={count}: too many for {n_moc} mocap samples; "
                             f"use at most {(n_moc - 20) // 10}")
        for start in np.sort(rng.choice(np.arange(10, n_moc - 10), size=count, replace=False)):
            length = int(rng.integers(1, 5))
            jump = rng.normal(size=3)
            jump *= rng.uniform(0.03, 0.10) / np.linalg.norm(jump)
            axis = rng.normal(size=3)
            rot = so3.exp(np.radians(rng.uniform(5, 30)) * axis / np.linalg.norm(axis))
            rows = np.arange(start, min(start + length, n_moc))
            p_meas[rows] += jump
            R_meas[rows] = R_meas[rows] @ rot
            outlier_rows.extend(int(r) for r in rows)
    keep = np.ones(n_moc, dtype=bool)
    gaps: list[list[float]] = []
    if "mocap_dropouts" in effects:
        v = effects["mocap_dropouts"]
        count = int(DEFAULT_MAGNITUDE["mocap_dropouts"] if v is None else v[0])
        for start in np.sort(rng.uniform(0.05, 0.95, count) * cfg.duration):
            length = rng.uniform(0.05, 1.0)
            keep &= ~((t_moc >= start) & (t_moc < start + length))
            gaps.append([float(start), float(length)])
    return t_moc, R_meas, p_meas, keep, outlier_rows, gaps


def _truth_file(cfg: SimConfig, effects: dict[str, list[float] | None], rig: _Rig, tr: _Truth,
                b_g: Array, b_a: Array) -> dict[str, Any]:
    """The truth in the result file's keys, the injected effects and how it was simulated."""
    truth: dict[str, Any] = {
        **header("calibration", 1),
        "gyro_bias": b_g.mean(axis=0).tolist(),
        "accel_bias": b_a.mean(axis=0).tolist(),
        "T_marker_imu": {
            "rotation_wxyz": so3.rotmat_to_quat(rig.R_MI).tolist(),
            "translation": rig.p_MI.tolist(),
        },
        "gravity_in_mocap": rig.g_dir.tolist(),
        "time_offset": float(tr.t_d),
        "sigma": {
            "gyro_bias": [0.0] * 3, "accel_bias": [0.0] * 3, "rotation": [0.0] * 3,
            "translation": [0.0] * 3, "gravity_in_mocap": [0.0] * 2, "time_offset": 0.0,
        },
        "gravity_magnitude": float(tr.g),
        "model": "+".join(["base", *[e for e in effects if e in CANONICAL_EFFECTS]]),
        "effects": {},
        "noise": cfg.noise.to_dict(),
        "simulation": {
            "seed": int(cfg.seed),
            "duration": float(cfg.duration),
            "imu_rate": float(cfg.imu_rate),
            "mocap_rate": float(cfg.mocap_rate),
            "mocap_noise_corr_s": float(cfg.mocap_noise_corr),
            **({"motion": cfg.motion} if cfg.motion != "flight" else {}),
            **({"max_motion_hz": float(cfg.max_motion_hz)} if cfg.max_motion_hz > 0 else {}),
            "bias_definition": "mean of the true bias over the IMU samples",
            "gyro_bias_initial": b_g[0].tolist(),
            "accel_bias_initial": b_a[0].tolist(),
        },
    }
    values = {"time_offset": float(tr.t_d), "gravity_magnitude": float(tr.g),
              "gyro_scale_misalignment": tr.M_g.tolist(),
              "accel_scale_misalignment": tr.M_a.tolist(), "gyro_g_sensitivity": tr.G.tolist(),
              "gyro_bias_drift": tr.dbg.tolist(), "accel_bias_drift": tr.dba.tolist(),
              "clock_drift": float(tr.drift), "accel_delay": float(tr.lag),
              "accel_size_effect": {"r_y": tr.r_size[0:3].tolist(),
                                    "r_z": tr.r_size[3:6].tolist()}}
    for name in effects:
        if name in EFFECTS:
            truth["effects"][name] = {EFFECTS[name].param: values[name]}
    return truth
