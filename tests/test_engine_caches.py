"""The window engine's shortcuts return what the plain computation does: the stamp search
against numpy's, the per-session smoothed signals, the lagged accelerometer resampled once per
evaluation, noise models run on the threads and the trajectory kept between noise batches."""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
import pytest

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.preint import hermite, search_sorted
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.position import motion
from mocap_calib.core.position.engine import PositionProblem, Theta, make_windows
from mocap_calib.core.threads import set_chunk_threads


@pytest.mark.parametrize("right", [False, True])
def test_search_sorted_is_numpys_searchsorted(right: bool) -> None:
    """Ascending, descending, random and repeated queries, ties with the stamps, NaN and
    infinities, empty inputs."""
    rng = np.random.default_rng(3)
    side = "right" if right else "left"
    for trial in range(400):
        n = int(rng.integers(0, 40))
        t = np.sort(rng.integers(0, 15, n).astype(float) if trial % 2 else rng.normal(size=n))
        q = rng.normal(0, 5, int(rng.integers(0, 60)))
        if trial % 3 == 0:
            q = np.sort(rng.integers(-2, 17, q.size).astype(float))
        if trial % 5 == 0:
            q = q[::-1].copy()
        if q.size > 2 and trial % 7 == 0:
            q[[0, -1]] = [np.nan, np.inf]
        if q.size > 1 and trial % 11 == 0:
            q[1] = -np.inf
        np.testing.assert_array_equal(search_sorted(t, q, right), np.searchsorted(t, q, side))
    grid = np.arange(1000) * 0.005
    nodes = np.sort(rng.uniform(0, 5, (4, 30, 7)), axis=None).reshape(4, 30, 7)
    got = search_sorted(grid, nodes, right)
    assert got.shape == nodes.shape
    np.testing.assert_array_equal(got, np.searchsorted(grid, nodes, side))


def test_smoothed_signals_are_kept_per_session_arrays() -> None:
    """The same sample arrays give the same (read-only) result without recomputing it; other
    arrays, or another band, are smoothed on their own."""
    rng = np.random.default_rng(0)
    u = np.arange(2000) * 0.005
    gyro, accel = rng.normal(size=(2000, 3)), rng.normal(size=(2000, 3))
    first = motion.motion_signals(u, gyro, accel, 50.0)
    again = motion.motion_signals(u, gyro, accel, 50.0)
    assert again[0] is first[0] and again[1] is first[1]
    assert not first[0].flags.writeable
    other_band = motion.motion_signals(u, gyro, accel, 25.0)
    assert not np.allclose(other_band[0], first[0])
    copy = motion.motion_signals(u, gyro.copy(), accel, 50.0)
    assert copy[0] is not first[0]
    np.testing.assert_array_equal(copy[0], first[0])
    # A smoothing of one constant signal is that constant (weights normalised).
    flat = motion.motion_signals(u, np.ones((2000, 3)), np.full((2000, 3), 9.81), 50.0)
    np.testing.assert_allclose(flat[0], 1.0, rtol=1e-14)
    np.testing.assert_allclose(flat[1], 9.81, rtol=1e-14)


def _theta(sim, s, W: int, lag: float) -> Theta:
    tr = sim.truth
    g = np.array(tr["gravity_in_mocap"])
    knots = np.tile(np.r_[tr["gyro_bias"], tr["accel_bias"]], (W, 1))
    return Theta(so3.quat_to_rotmat(np.array(tr["T_marker_imu"]["rotation_wxyz"])),
                 np.array(tr["T_marker_imu"]["translation"]), g, gtsam.Unit3(g).basis(), 9.81,
                 s.clock_shift + 0.003, {"accel_delay": np.array([lag])}, knots, 6.0)


def test_the_lagged_accelerometer_is_the_resampled_one(short_session) -> None:
    """With an accelerometer lag in the model, every chunk reads the series resampled once per
    lag: an evaluation equals one whose problem resamples afresh at every call, and a new lag
    is resampled again."""
    sim, s, v = short_session
    model = Model.parse("base+time_offset+accel_delay")
    win = make_windows(s, s.clock_shift + 0.003, 0.5, 200.0, v, min_samples=10)
    cached = PositionProblem(s, model, NoiseModel(), win)
    for lag in (0.002, -0.001, 0.002):
        th = _theta(sim, s, win.count, lag)
        fresh = PositionProblem(s, model, NoiseModel(), win)
        a, b = cached.evaluate(th), fresh.evaluate(th)
        for f in ("gram", "chi2", "logdet", "innovation"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    ut = s.u
    np.testing.assert_array_equal(cached._lagged("accel", ut, 0.002),
                                  hermite(ut, ut + 0.002)(s.accel))


def test_noise_models_on_threads_do_not_change_the_likelihoods(short_session) -> None:
    """A problem of one chunk runs its noise models on the threads: bit for bit the numbers of
    one thread."""
    sim, s, v = short_session
    win = make_windows(s, s.clock_shift + 0.003, 0.5, 200.0, v, min_samples=10)
    pp = PositionProblem(s, Model.parse("base+time_offset"), NoiseModel(), win, split=False)
    assert len(pp.chunks) == 1
    th = _theta(sim, s, win.count, 0.0)
    models = [NoiseModel(), NoiseModel(mocap_noise_corr_time=0.2, mocap_noise_corr_fraction=0.5),
              NoiseModel(accelerometer_noise_density=0.02)]
    previous = set_chunk_threads(2)
    try:
        two = pp.likelihoods(th, models)
        set_chunk_threads(1)
        one = pp.likelihoods(th, models)
    finally:
        set_chunk_threads(previous)
    for (c2, l2), (c1, l1) in zip(two, one, strict=True):
        np.testing.assert_array_equal(c2, c1)
        np.testing.assert_array_equal(l2, l1)
    assert not np.array_equal(two[0][0], two[2][0])  # the models differ


def test_the_trajectory_kept_between_noise_batches_is_the_parameters_own(short_session) -> None:
    """Likelihoods at the same parameters reuse the windows' trajectory: the numbers of a
    problem that integrates it afresh; other parameters get their own, not the kept one."""
    sim, s, v = short_session
    win = make_windows(s, s.clock_shift + 0.003, 0.5, 200.0, v, min_samples=10)
    model = Model.parse("base+time_offset")

    def fresh() -> PositionProblem:
        return PositionProblem(s, model, NoiseModel(), win, split=False)

    pp = fresh()
    th = _theta(sim, s, win.count, 0.0)
    moved = replace(th, p_MI=th.p_MI + 0.01)
    models = [NoiseModel(), NoiseModel(accelerometer_noise_density=0.02)]
    pp.likelihoods(th, models[:1])
    again = pp.likelihoods(th, models)  # the kept trajectory, another batch of models
    other = pp.likelihoods(moved, models)
    for (c, ld), (c0, ld0) in zip(again, fresh().likelihoods(th, models), strict=True):
        np.testing.assert_array_equal(c, c0)
        np.testing.assert_array_equal(ld, ld0)
    for (c, ld), (c0, ld0) in zip(other, fresh().likelihoods(moved, models), strict=True):
        np.testing.assert_array_equal(c, c0)
        np.testing.assert_array_equal(ld, ld0)
    assert not np.array_equal(again[0][0], other[0][0])  # the parameters matter
