"""Gyro and accelerometer logged apart, merged by the one reader-level step
(:mod:`mocap_calib.io.merge`): checked against an analytic signal sampled on offset clocks, at
gaps and ends, and through the readers that use it (a CSV with the two sensors on different
rows, imu_tk's two files)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mocap_calib.errors import InputError
from mocap_calib.io.loader import load_imu_file
from mocap_calib.io.merge import merge_on_gyro, split_rows

A = np.array([2.0, 1.0, 0.5])  # m/s^2
W = 2 * np.pi * np.array([7.0, 11.0, 3.0])  # rad/s
PHASE = np.array([0.3, 1.1, 2.0])


def accel_true(t_s: np.ndarray) -> np.ndarray:
    return A * np.sin(np.outer(t_s, W) + PHASE)


def clocks(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Gyro at 1 kHz and accelerometer at 800 Hz on its own clock (0.37 ms later), both with
    stamp jitter; integer ns."""
    rng = np.random.default_rng(seed)
    tg = 10_000_000_000 + np.arange(10_000) * 1_000_000 + rng.integers(-20_000, 20_000, 10_000)
    ta = 10_000_370_000 + np.arange(12_500) * 1_250_000 + rng.integers(-20_000, 20_000, 12_500)
    return tg.astype(np.int64), ta.astype(np.int64)


def test_interpolated_accel_matches_the_signal_within_the_derived_error() -> None:
    tg, ta = clocks()
    gyro = np.zeros((len(tg), 3))
    notes: list[str] = []
    t, _, acc = merge_on_gyro(tg, gyro, ta, accel_true((ta - tg[0]) * 1e-9),
                              label="log", notes=notes)
    # Linear interpolation over steps of at most h: |error| <= A w^2 h^2 / 8 per axis.
    h = np.max(np.diff(ta)) * 1e-9
    bound = A * W**2 * h**2 / 8
    err = np.abs(acc - accel_true((t - tg[0]) * 1e-9))
    assert np.all(err <= bound * (1 + 1e-9)), (err.max(axis=0), bound)
    # The bound is reached to within a factor of 2: the comparison can fail (a nearest-sample
    # merge would be off by A w h / 2, 20-60 times more).
    assert np.all(err.max(axis=0) > 0.5 * bound)
    # Every gyro stamp inside the accelerometer's span is kept; none outside.
    inside = (tg >= ta[0]) & (tg <= ta[-1])
    assert np.array_equal(t, tg[inside])
    assert any("gyro 10000 samples at 999.9 Hz" in n and "accelerometer 12500 at 800.0 Hz" in n
               and "interpolated linearly" in n for n in notes)


def test_never_across_an_accelerometer_gap_nor_beyond_its_ends() -> None:
    tg, ta = clocks(1)
    hole = (ta > tg[4000]) & (ta < tg[4060])  # a 60 ms accelerometer gap
    ta_gap = ta[~hole]
    left, right = ta_gap[np.flatnonzero(np.diff(ta_gap) > 10_000_000)[0] + np.array([0, 1])]
    notes: list[str] = []
    t, g, acc = merge_on_gyro(tg, np.arange(len(tg))[:, None] * np.ones(3), ta_gap,
                              accel_true((ta_gap - tg[0]) * 1e-9), label="log", notes=notes)
    in_gap = (tg > left) & (tg < right)
    outside = (tg < ta[0]) | (tg > ta[-1])
    assert in_gap.sum() > 50 and not np.isin(t, tg[in_gap]).any()
    assert not np.isin(t, tg[outside]).any()
    assert np.array_equal(g[:, 0], np.flatnonzero(~in_gap & ~outside))  # gyro rows unchanged
    left_out = int((in_gap | outside).sum())
    assert any(f"{left_out} gyro samples without accelerometer samples" in n for n in notes)


def test_equal_stamps_are_taken_as_they_are() -> None:
    tg, _ = clocks()
    acc = accel_true(tg * 1e-9)
    notes: list[str] = []
    t, _, out = merge_on_gyro(tg, np.zeros((len(tg), 3)), tg.copy(), acc, label="log",
                              notes=notes)
    assert np.array_equal(t, tg) and np.array_equal(out, acc) and not notes


def test_split_rows_are_recognised_only_when_systematic() -> None:
    g = np.ones((6, 3))
    a = np.ones((6, 3))
    g[1::2] = np.nan
    a[::2] = np.nan
    assert split_rows(g, a) is not None
    g2 = np.ones((6, 3))
    a2 = np.ones((6, 3))
    a2[3, 0] = np.nan  # one missing value: a bad row, not another sensor's row
    assert split_rows(g2, a2) is None
    a2[3] = np.nan  # only accelerometer rows missing: a dropout, not a split log
    assert split_rows(g2, a2) is None


def _split_csv(path: Path, tg: np.ndarray, ta: np.ndarray) -> Path:
    """A CSV with one row per sample of either sensor (the other's cells empty), by time."""
    rows = [(t, f"{t * 1e-9:.9f},0.01,0.02,0.03,,,") for t in tg]
    acc = accel_true((ta - tg[0]) * 1e-9) + [0.0, 0.0, 9.81]
    rows += [(t, f"{t * 1e-9:.9f},,,,{a[0]:.17g},{a[1]:.17g},{a[2]:.17g}")
             for t, a in zip(ta, acc, strict=True)]
    rows.sort(key=lambda r: r[0])
    path.write_text("t,gx,gy,gz,ax,ay,az\n" + "\n".join(r for _, r in rows) + "\n")
    return path


def test_csv_with_the_sensors_on_different_rows(tmp_path: Path) -> None:
    tg, ta = clocks(2)
    path = _split_csv(tmp_path / "split.csv", tg, ta)
    imu, notes = load_imu_file(path, columns="t=0,gyro=1:4,accel=4:7")
    inside = (tg >= ta[0]) & (tg <= ta[-1])
    assert np.array_equal(imu.stamps_ns(), tg[inside])
    h = np.max(np.diff(ta)) * 1e-9
    err = np.abs(imu.accel - [0.0, 0.0, 9.81] - accel_true((tg[inside] - tg[0]) * 1e-9))
    assert np.all(err <= A * W**2 * h**2 / 8 + 1e-12)
    assert any("different rows (10000 and 12500 rows)" in n for n in notes)
    # A clock reset on the gyro rows names the file's line.
    lines = path.read_text().splitlines()
    g_rows = [k for k, ln in enumerate(lines) if ln.endswith(",,,")]
    lines[g_rows[5000]] = "1.000000000" + lines[g_rows[5000]][lines[g_rows[5000]].index(","):]
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=f"line {g_rows[5000] + 1}: the gyro clock resets"):
        load_imu_file(bad, columns="t=0,gyro=1:4,accel=4:7")


def test_imu_tk_files_apart_go_through_the_same_step(tmp_path: Path) -> None:
    tg, ta = clocks(3)
    t0 = tg[0]
    gyro_file, accel_file = tmp_path / "gyro.txt", tmp_path / "acc.txt"
    gyro_file.write_text("\n".join(f"{(t - t0) * 1e-9:.9f} 0.01 0.02 0.03" for t in tg))
    acc = accel_true((ta - t0) * 1e-9) + [0.0, 0.0, 9.81]
    accel_file.write_text("\n".join(f"{(t - t0) * 1e-9:.9f} {a[0]:.17g} {a[1]:.17g} {a[2]:.17g}"
                                    for t, a in zip(ta, acc, strict=True)))
    imu, notes = load_imu_file(None, accel_file=accel_file, gyro_file=gyro_file)
    inside = (tg >= ta[0]) & (tg <= ta[-1])
    assert len(imu) == inside.sum()
    assert any("interpolated linearly onto the gyro stamps" in n for n in notes)
