"""Simulated multi-position sessions (Tedaldi et al., ICRA 2014) with known intrinsics.

A session is an initial static period, then a sequence of static orientations joined by smooth
rotations. Each rotation turns about one fixed body axis with a quintic angle profile, so the
body angular velocity is analytic (``theta'(t) * axis``) and the gyro samples are exact; a small
translation with the same profile adds a realistic linear acceleration. The measurements follow
``docs/conventions.md``: ``a_m = M_a f + b_a + n_a``, ``w_m = M_g w + G f + b_g + n_g`` (the
g-sensitivity ``G`` only when asked for). With ``counts`` the readings are written as a 16-bit
MEMS part would: ``raw = round(x / scale + offset)``, clipped to the part's range.
One seeded generator drives every random draw, in a fixed order, so the same arguments give the
same bytes; intrinsics passed explicitly replace the drawn ones without shifting other draws,
and ``G`` is drawn from a second generator, so a session with ``G`` differs from the one
without only by ``G f``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import of_term
from mocap_calib.core.model.types import ImuSamples, NoiseModel
from mocap_calib.core.policy import GRAVITY, STANDARD_GRAVITY
from mocap_calib.errors import InputError
from mocap_calib.sim.injected import sim_of

Array = NDArray[np.float64]

_UP = np.array([0.0, 0.0, 1.0])


def _smoothstep(tau: Array) -> tuple[Array, Array, Array]:
    """Quintic ``s(tau)`` on [0, 1] with zero first and second derivatives at both ends."""
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    ds = 30.0 * tau**2 * (1.0 - tau) ** 2
    dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)
    return s, ds, dds


def _fibonacci_sphere(n: int) -> Array:
    """``n`` unit vectors spread almost uniformly over the sphere."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * k
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _greedy_tour(points: Array, start: int) -> list[int]:
    """Visit every point, always moving to the nearest unvisited one (moderate rotations)."""
    order = [start]
    left = set(range(len(points))) - {start}
    while left:
        cand = np.array(sorted(left))
        nxt = int(cand[np.argmax(points[cand] @ points[order[-1]])])
        order.append(nxt)
        left.remove(nxt)
    return order


def _rot_z(psi: float) -> Array:
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def default_intrinsics(rng: np.random.Generator) -> dict[str, Array]:
    """Realistic MEMS intrinsics: scale errors 0.2-1 %, misalignments 0.1-0.5 deg.

    ``M_a = diag(s_a) (I + L)`` with ``L`` strictly lower-triangular (the IMU frame is the
    accelerometer's orthogonalised frame); ``M_g = diag(s_g) (I + O)`` with ``O`` a full
    off-diagonal matrix (gyro axes misaligned relative to that frame).
    """

    def signed(lo: float, hi: float, size: int) -> Array:
        return rng.choice([-1.0, 1.0], size) * rng.uniform(lo, hi, size)

    s_a = 1.0 + signed(0.002, 0.01, 3)
    lower = np.zeros((3, 3))
    lower[np.tril_indices(3, -1)] = np.radians(signed(0.1, 0.5, 3))
    s_g = 1.0 + signed(0.002, 0.01, 3)
    off = np.zeros((3, 3))
    off[~np.eye(3, dtype=bool)] = np.radians(signed(0.1, 0.5, 6))
    return {
        "accel_matrix": np.diag(s_a) @ (np.eye(3) + lower),
        "accel_bias": rng.uniform(-0.2, 0.2, 3),
        "gyro_matrix": np.diag(s_g) @ (np.eye(3) + off),
        "gyro_bias": rng.uniform(-0.02, 0.02, 3),
    }


def _check_given(name: str, value: ArrayLike | None, shape: tuple[int, ...]) -> Array | None:
    if value is None:
        return None
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: expected {shape} finite values, got shape {arr.shape}")
    return arr


#: Default magnitude of ``G``: std of its entries, rad/s per m/s^2 (the effect registry's
#: simulation default, as the flight simulator draws it).
G_STD: float = sim_of(of_term("gyro", "f")).default


@dataclass(frozen=True)
class CountsSpec:
    """How a 16-bit MEMS part turns SI readings into counts: ``raw = x / scale + offset``,
    rounded and clipped to ``[lo, hi]``.

    Defaults: an accelerometer at +-8 g (4096 LSB/g) and a gyroscope at +-2000 deg/s
    (16.4 LSB per deg/s), signed outputs (offset 0).
    """

    accel_scale: float = STANDARD_GRAVITY / 4096.0
    accel_offset: float = 0.0
    gyro_scale: float = float(np.radians(1.0)) / 16.4
    gyro_offset: float = 0.0
    lo: float = -32768.0
    hi: float = 32767.0

    def convert(self, x: Array, sensor: str) -> Array:
        scale, offset = ((self.accel_scale, self.accel_offset) if sensor == "accel"
                         else (self.gyro_scale, self.gyro_offset))
        return np.clip(np.round(x / scale + offset), self.lo, self.hi)

    def to_dict(self) -> dict[str, Any]:
        return {"accel_scale": [self.accel_scale] * 3, "accel_offset": [self.accel_offset] * 3,
                "gyro_scale": [self.gyro_scale] * 3, "gyro_offset": [self.gyro_offset] * 3,
                "range": [self.lo, self.hi],
                "model": "raw = round(x / scale + offset); x in m/s^2 and rad/s"}


def _g_matrix(seed: int, g_sensitivity: ArrayLike | float | None) -> Array | None:
    """``G`` from a value (a 3x3 matrix, or the std of its entries) drawn from a generator of
    its own."""
    if g_sensitivity is None:
        return None
    v = np.asarray(g_sensitivity, dtype=float)
    if v.size == 9:
        return v.reshape(3, 3)
    if v.size != 1 or not (np.isfinite(v) and float(v) >= 0):
        raise InputError("g_sensitivity: give 9 values or one non-negative std (rad/s per "
                         "m/s^2)")
    return np.random.default_rng([seed, 7]).normal(0.0, float(v), (3, 3))


def _orientations(rng: np.random.Generator, n_orientations: int, init_static_s: float,
                  static_s: float) -> dict[str, Any]:
    """Static attitudes (body "up" spread over the sphere, visited nearest-first from the one
    closest to +z, with a random yaw walk), hold times and the rotations between them."""
    ups = _fibonacci_sphere(n_orientations)
    q = rng.normal(size=4)
    ups = ups @ so3.quat_to_rotmat(q / np.linalg.norm(q)).T
    order = _greedy_tour(ups, int(np.argmax(ups[:, 2])))
    ups = ups[order]
    psi = rng.uniform(-np.pi, np.pi) + np.cumsum(rng.uniform(-0.6, 0.6, n_orientations))
    # R_WI maps the body up vector onto world up; yaw about world up is free.
    R_static = np.stack([_rot_z(p) @ so3.rotation_between(u, _UP) for u, p in zip(ups, psi,
                                                                                strict=True)])
    holds = np.concatenate([[init_static_s],
                            static_s * rng.uniform(0.85, 1.15, n_orientations - 1)])
    rot_axis, rot_angle, rot_dur, shifts = [], [], [], []
    for j in range(n_orientations - 1):
        phi = so3.log(R_static[j].T @ R_static[j + 1])
        ang = float(np.linalg.norm(phi))
        rot_axis.append(phi / ang if ang > 1e-12 else np.array([1.0, 0.0, 0.0]))
        rot_angle.append(ang)
        rot_dur.append(1.0 + ang / np.pi + rng.uniform(0.0, 0.3))  # 1-2.3 s, longer for bigger
        d = rng.normal(size=3)
        shifts.append(d / np.linalg.norm(d) * rng.uniform(0.02, 0.08))  # hand moves 2-8 cm
    return {"ups": ups, "R": R_static, "holds": holds, "axis": rot_axis, "angle": rot_angle,
            "dur": rot_dur, "shift": shifts}


def _motion(o: dict[str, Any], n_orientations: int, rate_hz: float, gravity: float
            ) -> tuple[Array, Array, Array, list[list[float]]]:
    """Times, body rates, specific forces and the true static intervals of the session
    (hold 0, rotation 0, hold 1, ..., hold n-1)."""
    bounds = [0.0]
    for j in range(n_orientations):
        bounds.append(bounds[-1] + o["holds"][j])
        if j < n_orientations - 1:
            bounds.append(bounds[-1] + o["dur"][j])
    n = int(np.floor(bounds[-1] * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    w_I = np.zeros((n, 3))
    f_I = np.zeros((n, 3))
    static_intervals = []
    for j in range(n_orientations):
        h0, h1 = bounds[2 * j], bounds[2 * j + 1]
        sel = (t >= h0) & (t < h1) if j < n_orientations - 1 else (t >= h0)
        f_I[sel] = gravity * (o["R"][j].T @ _UP)
        static_intervals.append([float(h0), float(min(h1, t[-1]))])
        if j == n_orientations - 1:
            break
        r0, r1 = h1, bounds[2 * j + 2]
        sel = (t >= r0) & (t < r1)
        T = r1 - r0
        s, ds, dds = _smoothstep((t[sel] - r0) / T)
        theta = o["angle"][j] * s
        w_I[sel] = np.outer(o["angle"][j] * ds / T, o["axis"][j])
        R = o["R"][j] @ so3.exp(np.outer(theta, o["axis"][j]))
        a_W = np.outer(dds / T**2, o["shift"][j])
        # f = R_WI^T (a_W - g_W) with g_W = -g z.
        f_I[sel] = np.einsum("nji,nj->ni", R, a_W + gravity * _UP)
    return t, w_I, f_I, static_intervals


def _check_args(n_orientations: int, static_s: float, init_static_s: float,
                rate_hz: float) -> None:
    if n_orientations < 2:
        raise InputError(f"n_orientations={n_orientations}: need at least 2")
    if not (static_s > 0 and init_static_s > 0):
        raise InputError("static_s and init_static_s must be positive")
    if not 10.0 <= rate_hz <= 10000.0:
        raise InputError(f"rate_hz={rate_hz}: must be between 10 and 10000 Hz")


def simulate_multipos(
    seed: int,
    n_orientations: int = 40,
    static_s: float = 3.0,
    init_static_s: float = 40.0,
    rate_hz: float = 200.0,
    noise: NoiseModel | None = None,
    accel_matrix: ArrayLike | None = None,
    accel_bias: ArrayLike | None = None,
    gyro_matrix: ArrayLike | None = None,
    gyro_bias: ArrayLike | None = None,
    gravity: float = GRAVITY,
    bias_random_walk: bool = False,
    time_origin_ns: int = 1_600_000_000_000_000_000,
    g_sensitivity: ArrayLike | float | None = None,
    counts: CountsSpec | None = None,
) -> tuple[ImuSamples, dict[str, Any]]:
    """Simulate one multi-position calibration session.

    Args:
        seed: seed of the random generator (same seed, same output).
        n_orientations: number of static orientations, the initial static period included.
        static_s: nominal hold time of each orientation after the first (jittered +-15 %).
        init_static_s: length of the initial static period.
        rate_hz: IMU sample rate.
        noise: white-noise densities (and random-walk densities if ``bias_random_walk``);
            default EuRoC's ADIS16448 values.
        accel_matrix: ``M_a`` (lower-triangular 3x3); default drawn from the seed.
        accel_bias: ``b_a`` in m/s^2; default drawn from the seed.
        gyro_matrix: ``M_g`` (3x3); default drawn from the seed.
        gyro_bias: ``b_g`` in rad/s; default drawn from the seed.
        gravity: ``|g|`` in m/s^2.
        bias_random_walk: add the noise model's bias random walks (off by default: the
            protocol assumes constant biases over a few minutes).
        time_origin_ns: stamp of the first sample.
        g_sensitivity: ``G`` (9 values, rad/s per m/s^2) or the std of its entries (e.g.
            :data:`G_STD`); None: no g-sensitivity.
        counts: write raw counts of a 16-bit part instead of SI readings.

    Returns:
        The IMU samples and a truth dict with the intrinsics keys of ``docs/conventions.md``
        (``accel_matrix``, ``accel_bias``, ``gyro_matrix``, ``gyro_bias``, ``g_sensitivity``
        if simulated; biases are the mean over the session; all for SI readings, which
        ``counts`` relates to the raw counts), ``gravity_magnitude``, ``noise`` and
        ``simulation`` (true static periods in seconds, the body "up" direction of every
        orientation, ...).
    """
    _check_args(n_orientations, static_s, init_static_s, rate_hz)
    noise = NoiseModel() if noise is None else noise
    rng = np.random.default_rng(seed)
    intr = _intrinsics(rng, accel_matrix, accel_bias, gyro_matrix, gyro_bias)
    G = _g_matrix(seed, g_sensitivity)
    o = _orientations(rng, n_orientations, init_static_s, static_s)
    t, w_I, f_I, static_intervals = _motion(o, n_orientations, rate_hz, gravity)
    n = len(t)
    dt = 1.0 / rate_hz
    b_g = np.broadcast_to(intr["gyro_bias"], (n, 3)).copy()
    b_a = np.broadcast_to(intr["accel_bias"], (n, 3)).copy()
    if bias_random_walk:
        b_g += np.cumsum(rng.normal(0.0, noise.gyroscope_random_walk * np.sqrt(dt), (n, 3)), 0)
        b_a += np.cumsum(rng.normal(0.0, noise.accelerometer_random_walk * np.sqrt(dt),
                                    (n, 3)), 0)
    n_g = rng.normal(0.0, noise.gyroscope_noise_density * np.sqrt(rate_hz), (n, 3))
    n_a = rng.normal(0.0, noise.accelerometer_noise_density * np.sqrt(rate_hz), (n, 3))
    gyro = w_I @ intr["gyro_matrix"].T + b_g + n_g
    if G is not None:
        gyro = gyro + f_I @ G.T
    accel = f_I @ intr["accel_matrix"].T + b_a + n_a
    if counts is not None:
        gyro, accel = counts.convert(gyro, "gyro"), counts.convert(accel, "accel")
    imu = ImuSamples(t, gyro, accel, time_origin_ns, "simulated multipos imu")
    truth = _truth(intr, b_g, b_a, G, counts, gravity, noise, o, static_intervals, {
        "seed": int(seed), "protocol": "multipos", "n_orientations": int(n_orientations),
        "init_static_s": float(init_static_s), "static_s": float(static_s),
        "rate_hz": float(rate_hz), "duration": float(t[-1]),
        "bias_random_walk": bool(bias_random_walk)})
    return imu, truth


def _intrinsics(rng: np.random.Generator, accel_matrix: ArrayLike | None,
                accel_bias: ArrayLike | None, gyro_matrix: ArrayLike | None,
                gyro_bias: ArrayLike | None) -> dict[str, Array]:
    """Drawn intrinsics, replaced by the given ones. They are always drawn first so that
    passing some of them keeps the rest (and every later draw) identical."""
    intr = default_intrinsics(rng)
    given = {
        "accel_matrix": _check_given("accel_matrix", accel_matrix, (3, 3)),
        "accel_bias": _check_given("accel_bias", accel_bias, (3,)),
        "gyro_matrix": _check_given("gyro_matrix", gyro_matrix, (3, 3)),
        "gyro_bias": _check_given("gyro_bias", gyro_bias, (3,)),
    }
    for k, v in given.items():
        if v is not None:
            intr[k] = v
    if np.any(np.abs(np.triu(intr["accel_matrix"], 1)) > 0):
        raise InputError("accel_matrix must be lower-triangular: the IMU frame is the "
                         "accelerometer's orthogonalised frame (docs/conventions.md)")
    return intr


def _truth(intr: dict[str, Array], b_g: Array, b_a: Array, G: Array | None,
           counts: CountsSpec | None, gravity: float, noise: NoiseModel, o: dict[str, Any],
           static_intervals: list[list[float]], sim: dict[str, Any]) -> dict[str, Any]:
    truth: dict[str, Any] = {
        "accel_matrix": intr["accel_matrix"].tolist(),
        "accel_bias": b_a.mean(axis=0).tolist(),
        "gyro_matrix": intr["gyro_matrix"].tolist(),
        "gyro_bias": b_g.mean(axis=0).tolist(),
        "gravity_magnitude": float(gravity),
        "model": ["base", "accel_scale_misalignment", "gyro_scale_misalignment"],
        "noise": noise.to_dict(),
        "simulation": {
            **sim,
            "bias_definition": "mean of the true bias over the IMU samples",
            "static_intervals_s": static_intervals,
            "up_vectors_imu": o["ups"].tolist(),
            "rotation_angles_deg": np.degrees(o["angle"]).tolist(),
        },
    }
    if G is not None:
        truth["g_sensitivity"] = G.tolist()
        truth["model"].append("gyro_g_sensitivity")
    if counts is not None:
        truth["counts"] = counts.to_dict()
    return truth
