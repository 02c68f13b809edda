"""Simulated mocap flights with known truth.

The IMU samples are computed exactly from the trajectory's analytic derivatives through the
measurement model of ``docs/conventions.md``; the mocap poses are the exact marker poses plus
noise. Effects beyond the base model are injected as their registry records say
(:mod:`mocap_calib.sim.injected`) and applied here by kind; a real flight's roughness (white
noise above the data sheet, rotor vibration: :mod:`mocap_calib.sim.vibration`) is switched on
per knob. One seeded generator drives the draws of the rig, the effects and the noise, in a
fixed order; every other stream (other motions, vibration, IMU logging faults) has a generator
of its own seeded from the same seed, so the same configuration gives the same bytes and a knob
switched on leaves every other draw as it was.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import EFFECTS
from mocap_calib.core.model.types import ImuSamples, MocapPoses, NoiseModel
from mocap_calib.core.policy import GRAVITY
from mocap_calib.core.versioned import header
from mocap_calib.errors import InputError
from mocap_calib.sim.injected import (
    OWN_QUANTITY,
    Truth,
    draw_truth,
    effect_help,
    parse_effect,
    truth_effects,
)
from mocap_calib.sim.motions import MOTIONS, motion_trajectory
from mocap_calib.sim.stream_faults import FAULTS, imu_gaps, mocap_dropouts, mocap_outliers
from mocap_calib.sim.trajectory import (
    Trajectory,
    periodic_trajectory,
    random_trajectory,
    with_fast_motion,
)
from mocap_calib.sim.vibration import Rotors, Vibration, draw_rotors, vibration_truth

Array = NDArray[np.float64]

#: Faults only the simulator knows (of the streams, not of the IMU model).
SIM_FAULTS: tuple[str, ...] = tuple(FAULTS)

__all__ = ["SIM_FAULTS", "SimConfig", "SimulatedSession", "effect_help", "parse_effect",
           "simulate_flight"]


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
    # A real flight's roughness, each off by default. ``noise`` holds the data sheet's
    # densities; the white noise simulated is these factors times them.
    gyro_noise_factor: float = 1.0
    accel_noise_factor: float = 1.0
    vibration: Vibration = Vibration()
    preset: str = "none"  # the named regime this came from (sim.presets), for the truth file

    @property
    def true_noise(self) -> NoiseModel:
        """The noise simulated: ``noise`` with its white densities times the factors."""
        n = self.noise
        return replace(n, gyroscope_noise_density=n.gyroscope_noise_density
                       * self.gyro_noise_factor,
                       accelerometer_noise_density=n.accelerometer_noise_density
                       * self.accel_noise_factor)

    @property
    def rough(self) -> bool:
        """Whether any in-flight roughness beyond the data sheet is on."""
        return self.vibration.on or (self.gyro_noise_factor, self.accel_noise_factor) != (1, 1)

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
        for name, factor in (("gyro", self.gyro_noise_factor),
                             ("accel", self.accel_noise_factor)):
            if not 0.0 < factor <= 1000.0:
                raise InputError(f"--{name}-noise-factor {factor:g}: give the white noise's "
                                 "density as a multiple of the data sheet's, above 0 and at "
                                 "most 1000")
        self.vibration.validate()
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
    tr = draw_truth(rng, effects, cfg.gravity)
    # Rotor vibration: its own generator, so every other draw stays the seed's.
    rotors = (draw_rotors(np.random.default_rng([cfg.seed, 53]), cfg.vibration)
              if cfg.vibration.on else None)
    t_imu, gyro, accel, b_g, b_a = _imu_samples(rng, cfg, traj, rig, tr, rotors)
    t_moc, R_meas, p_meas, keep, outlier_rows, gaps = _mocap_samples(rng, cfg, traj, rig,
                                                                     effects)
    # IMU logging faults last, with their own generator: every other draw stays the seed's.
    kept, dropped = imu_gaps(np.random.default_rng([cfg.seed, 41]), cfg.duration, t_imu,
                             effects)
    in_flight = _in_flight(cfg, rotors, t_imu) if cfg.rough else None
    t_imu, gyro, accel, b_g, b_a = (x[kept] for x in (t_imu, gyro, accel, b_g, b_a))
    imu = ImuSamples(t_imu, gyro, accel, cfg.imu_time_origin_ns, "simulated imu")
    mocap = MocapPoses(t_moc[keep], so3.rotmat_to_quat(R_meas[keep]), p_meas[keep],
                       cfg.mocap_time_origin_ns, "simulated mocap")
    truth = _truth_file(cfg, effects, rig, tr, b_g, b_a)
    if in_flight is not None:
        truth["simulation"]["in_flight"] = in_flight
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


def _imu_samples(rng: np.random.Generator, cfg: SimConfig, traj: Trajectory, rig: _Rig,
                 tr: Truth, rotors: Rotors | None) -> tuple[Array, Array, Array, Array, Array]:
    """IMU stamps on the IMU clock; a gyro sample stamped ``t`` was measured at mocap time
    ``t + t_d + s (t - t_mid)``, an accel sample ``lag`` earlier. Each sensor measures its own
    quantity through ``I + E`` and the other through its cross term (when the registry has
    one), plus its bias (random walk and trend) and white noise."""
    noise = cfg.true_noise
    n_imu = int(round(cfg.duration * cfg.imu_rate)) + 1
    t_imu = np.arange(n_imu) / cfg.imu_rate
    t_mid = 0.5 * (t_imu[0] + t_imu[-1])
    s_g = t_imu + tr.t_d + tr.drift * (t_imu - t_mid)
    s_a = s_g - tr.lag
    at_gyro, at_accel = _true_signals(traj, rig, tr, rotors, s_g, s_a)
    dt = 1.0 / cfg.imu_rate
    rw_g = np.cumsum(rng.normal(0.0, noise.gyroscope_random_walk * np.sqrt(dt), (n_imu, 3)), 0)
    rw_a = np.cumsum(rng.normal(0.0, noise.accelerometer_random_walk * np.sqrt(dt), (n_imu, 3)), 0)
    rw_g -= rw_g[0]
    rw_a -= rw_a[0]
    b_g = rig.bg0 + rw_g + np.outer(t_imu - t_mid, tr.bias_rate("gyro"))
    b_a = rig.ba0 + rw_a + np.outer(t_imu - t_mid, tr.bias_rate("accel"))
    n_g = rng.normal(0.0, noise.gyroscope_noise_density * np.sqrt(cfg.imu_rate), (n_imu, 3))
    n_a = rng.normal(0.0, noise.accelerometer_noise_density * np.sqrt(cfg.imu_rate), (n_imu, 3))
    gyro = _sensed(tr, "gyro", at_gyro) + b_g + n_g
    accel = _sensed(tr, "accel", at_accel) + b_a + n_a
    return t_imu, gyro, accel, b_g, b_a


def _sensed(tr: Truth, sensor: str, at: dict[str, Callable[[], Array]]) -> Array:
    """The sensor's reading without bias and noise: ``M q_own + sum E q_other``, with a term
    for every other quantity the registry has a matrix effect of for this sensor."""
    own = OWN_QUANTITY[sensor]
    terms = {e.acts_on for e in EFFECTS.values() if e.sensor == sensor}
    out = at[own]() @ tr.sensor_matrix(sensor, own).T
    for q in ("w", "f"):
        if q != own and q in terms:
            out = out + at[q]() @ tr.sensor_matrix(sensor, q).T
    return out


def _true_signals(traj: Trajectory, rig: _Rig, tr: Truth, rotors: Rotors | None, s_g: Array,
                  s_a: Array) -> tuple[dict[str, Callable[[], Array]],
                                       dict[str, Callable[[], Array]]]:
    """The true rate ``w`` and specific force ``f`` at the gyro's and at the accelerometer's
    instants (computed when asked for), with the size effect on the accelerometer's ``f``
    and the rotor vibration on both."""

    def rate(s: Array) -> Array:
        w = traj.angular_velocity_body(s)
        return w if rotors is None else w + rotors.signal(s, rotors.amp_gyro)

    def force(s: Array) -> Array:
        f = np.einsum("nji,nj->ni", traj.rotation(s), traj.acceleration(s) - tr.g * rig.g_dir)
        return f if rotors is None else f + rotors.signal(s, rotors.amp_accel)

    f_g = force(s_g)
    f_a = f_g if tr.lag == 0.0 else force(s_a)
    if np.any(tr.r_size):
        # y and z accelerometers at r_y, r_z: e_i.(alpha x r_i + w x (w x r_i)).
        e = 1e-5
        w_a = traj.angular_velocity_body(s_a)
        w_rate = traj.angular_velocity_body
        alpha = (w_rate(s_a + e) - w_rate(s_a - e)) / (2 * e)
        f_a = f_a.copy()
        for i, r in ((1, tr.r_size[0:3]), (2, tr.r_size[3:6])):
            f_a[:, i] += (np.cross(alpha, r) + np.cross(w_a, np.cross(w_a, r)))[:, i]
    return ({"w": lambda: rate(s_g), "f": lambda: f_g},
            {"w": lambda: rate(s_a), "f": lambda: f_a})


def _mocap_samples(rng: np.random.Generator, cfg: SimConfig, traj: Trajectory, rig: _Rig,
                   effects: dict[str, list[float] | None]):
    """Marker poses ``T_WM = T_WI T_MI^-1`` at mocap stamps plus noise, marker swaps and
    dropouts: (stamps, R, p, rows kept, outlier rows, gaps)."""
    noise = cfg.true_noise
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
    outlier_rows = mocap_outliers(rng, effects, R_meas, p_meas)
    keep, gaps = mocap_dropouts(rng, effects, t_moc, cfg.duration)
    return t_moc, R_meas, p_meas, keep, outlier_rows, gaps


def _truth_file(cfg: SimConfig, effects: dict[str, list[float] | None], rig: _Rig, tr: Truth,
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
        "model": "+".join(["base", *[e for e in effects if e in EFFECTS]]),
        "effects": truth_effects(effects, tr),
        "noise": cfg.true_noise.to_dict(),
        "simulation": {
            "seed": int(cfg.seed),
            "duration": float(cfg.duration),
            "imu_rate": float(cfg.imu_rate),
            "mocap_rate": float(cfg.mocap_rate),
            "mocap_noise_corr_s": float(cfg.mocap_noise_corr),
            **({"motion": cfg.motion} if cfg.motion != "flight" else {}),
            **({"max_motion_hz": float(cfg.max_motion_hz)} if cfg.max_motion_hz > 0 else {}),
            **({"preset": cfg.preset} if cfg.preset != "none" else {}),
            "bias_definition": "mean of the true bias over the IMU samples",
            "gyro_bias_initial": b_g[0].tolist(),
            "accel_bias_initial": b_a[0].tolist(),
        },
    }
    return truth


def _in_flight(cfg: SimConfig, rotors: Rotors | None, t_imu: Array) -> dict[str, Any]:
    """The truth file's record of the roughness beyond the data sheet: the white noise
    factors and the data sheet's densities (``noise`` holds the true ones), the vibration,
    and per axis the total white-equivalent density (white and vibration in quadrature)."""
    true = cfg.true_noise
    out: dict[str, Any] = {
        "white_noise_factor": {"gyroscope": float(cfg.gyro_noise_factor),
                               "accelerometer": float(cfg.accel_noise_factor)},
        "data_sheet_noise": {"gyroscope_noise_density": cfg.noise.gyroscope_noise_density,
                             "accelerometer_noise_density":
                                 cfg.noise.accelerometer_noise_density},
    }
    vib_g = vib_a = np.zeros(3)
    if rotors is not None:
        vib = vibration_truth(rotors, t_imu, cfg.imu_rate)
        out["vibration"] = vib
        vib_g = np.asarray(vib["effective_density_gyro"])
        vib_a = np.asarray(vib["effective_density_accel"])
    out["total_density_gyro"] = np.hypot(true.gyroscope_noise_density, vib_g).tolist()
    out["total_density_accel"] = np.hypot(true.accelerometer_noise_density, vib_a).tolist()
    return out
