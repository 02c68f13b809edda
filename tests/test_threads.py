"""Work split into blocks on the threads gives the numbers of one thread, bit for bit: the
rotation logs, the preintegration and the pose screen of a whole session, and the clock
search."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from mocap_calib.core import threads
from mocap_calib.core.clock.search import search_clock
from mocap_calib.core.model import so3
from mocap_calib.core.model.preint import integrate_pieces
from mocap_calib.core.model.so3_compiled import log_kernel
from mocap_calib.core.prepare.pose_screen import screen_poses
from mocap_calib.core.threads import map_blocks, set_chunk_threads
from mocap_calib.sim.flight import SimConfig, simulate_flight


@pytest.fixture
def one_thread():
    """Runs its argument on one thread, then restores the count."""
    def run(fn):
        previous = set_chunk_threads(1)
        try:
            return fn()
        finally:
            set_chunk_threads(previous)
    return run


def test_map_blocks_keeps_order_and_never_nests() -> None:
    """Results in the items' order; a block that maps again runs its items in its own
    thread (a pool of two waiting on itself would never finish)."""
    previous = set_chunk_threads(2)
    try:
        assert map_blocks(lambda i: i * i, range(7)) == [0, 1, 4, 9, 16, 25, 36]
        seen: list[str] = []

        def outer(i: int) -> list[int]:
            def inner(j: int) -> int:
                seen.append(threading.current_thread().name)
                return 10 * i + j
            return map_blocks(inner, range(3))

        assert map_blocks(outer, range(2)) == [[0, 1, 2], [10, 11, 12]]
        assert all(name.startswith(threads._PREFIX) for name in seen)
    finally:
        set_chunk_threads(previous)


def test_rotation_logs_in_blocks(one_thread) -> None:
    rng = np.random.default_rng(2)
    R = so3.exp(rng.normal(0, 1.5, (7 * (so3.LOG_BLOCK // 2 + 5), 3)))
    R[5] = so3.exp(np.array([np.pi, 0.0, 0.0]))  # the far end of the range
    blocked = so3.log(R.reshape(-1, 7, 3, 3))
    assert blocked.shape == (len(R) // 7, 7, 3)
    plain = np.empty((len(R), 3))  # the compiled log in one pass over every rotation
    one_thread(lambda: log_kernel(np.ascontiguousarray(R), plain))
    np.testing.assert_array_equal(blocked.reshape(-1, 3), plain)


def test_preintegration_in_blocks(one_thread) -> None:
    rng = np.random.default_rng(3)
    S, n = 3000, 12
    w, f = rng.normal(0, 1, (S, 2 * n + 1, 3)), rng.normal(0, 5, (S, 2 * n + 1, 3))
    hs = np.full((S, n), 0.005)
    hs[7, -3:] = 0.0  # padding
    two = integrate_pieces(w, f, hs).pack()
    one = one_thread(lambda: integrate_pieces(w, f, hs).pack())
    np.testing.assert_array_equal(two, one)


def test_pose_screen_and_clock_search_in_blocks(one_thread) -> None:
    sim = simulate_flight(SimConfig(seed=3, duration=60.0, effects={"time_offset": [0.004]}))
    m, imu = sim.mocap, sim.imu
    t = m.t
    R, p = m.rotation, m.position.copy()
    p[1000] += 0.05  # a jump to find

    def screen():
        return screen_poses(t, R, p, 0.05, 5e-4, np.deg2rad(0.05))

    two, one = screen(), one_thread(screen)
    assert two.jumps[1000] and np.array_equal(two.jumps, one.jumps)
    assert (two.sigma_position_m, two.sigma_rotation_rad) == (one.sigma_position_m,
                                                               one.sigma_rotation_rad)
    u = imu.t
    shift = (imu.time_origin_ns - m.time_origin_ns) * 1e-9

    def search():
        return search_clock(u, imu.gyro, imu.accel, t, R, p, shift)

    a, b = search(), one_thread(search)
    assert a.time_offset == b.time_offset
    assert a.time_offset == pytest.approx(sim.truth["time_offset"], abs=2e-3)
