"""Gyro and accelerometer logged apart, merged into one IMU stream: the step every reader
uses when a format keeps the two sensors' samples separately (a Crazyflie uSD log's two
events, PX4's ``sensor_gyro``/``sensor_accel`` or ``sensor_combined``'s relative stamps, a CSV
whose gyro and accelerometer readings sit on different rows).

The rule (also in ``docs/flight_logs_io.md``):

- The merged stream has the gyro's stamps and the gyro's samples unchanged: the gyro is
  integrated sample by sample, so its samples are never resampled.
- The accelerometer at a gyro stamp is its own sample where one has that stamp; otherwise it
  is interpolated linearly between the two accelerometer samples around the stamp, when those
  two are no further apart than the gap rule allows (:func:`~mocap_calib.core.policy.gap_threshold`
  of the accelerometer's stamps: 3 of its median steps).
- Gyro samples before the first or after the last accelerometer sample, or inside an
  accelerometer gap, are left out: the accelerometer is never extrapolated and never bridged
  across a gap. A note says how many, with both streams' rates.

Error of the interpolation: for accelerometer samples ``h`` apart, linear interpolation is off
by at most ``h^2 / 8 max|a''|``; for a sinusoid ``A sin(w t)`` that is ``A w^2 h^2 / 8`` (at 1 kHz
and 10 Hz motion of 1 m/s^2: 5e-5 m/s^2, far below any accelerometer's noise).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.policy import gap_threshold
from mocap_calib.io.streams import ImuTable
from mocap_calib.io.validate import Lines, check_increasing

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]


def _rate(stamps: IntArray, ns_per_unit: int) -> float:
    step = float(np.median(np.diff(stamps))) * ns_per_unit if len(stamps) > 1 else 0.0
    return 1e9 / step if step > 0 else 0.0


def merge_on_gyro(t_gyro: IntArray, gyro: Array, t_accel: IntArray, accel: Array, *,
                  label: str, notes: list[str], ns_per_unit: int = 1,
                  lines: Lines | None = None) -> tuple[IntArray, Array, Array]:
    """Gyro and accelerometer samples on the gyro's stamps (the rule of the module doc).

    Args:
        t_gyro: (N,) integer gyro stamps, increasing, in any unit (``ns_per_unit`` ns each).
        gyro: (N, 3) gyro samples.
        t_accel: (M,) integer accelerometer stamps, increasing, same unit.
        accel: (M, 3) accelerometer samples.
        label: The source for messages and the note.
        notes: Where the note on the merge goes (none when the stamps are equal).
        ns_per_unit: Nanoseconds per stamp unit (for the note's figures).
        lines: Row-to-line map of the gyro's rows, for a message naming a line.

    Returns:
        (stamps, gyro, accel) of the gyro samples kept, stamps in the input's unit.

    Raises:
        InputError: when either stream's stamps do not increase, or fewer than two
            accelerometer samples are given.
    """
    if len(t_gyro) == len(t_accel) and np.array_equal(t_gyro, t_accel):
        return t_gyro, gyro, accel
    where = lines or Lines(label)
    check_increasing(t_accel * ns_per_unit, "accelerometer", Lines(label))
    check_increasing(t_gyro * ns_per_unit, "gyro", where)
    if len(t_accel) < 2:
        raise where.error(f"{len(t_accel)} accelerometer samples against {len(t_gyro)} gyro "
                          "samples: nothing to interpolate from",
                          "pass a log that holds the accelerometer's samples")
    tg, ta = t_gyro, t_accel
    j = np.searchsorted(ta, tg, side="right")  # ta[j-1] <= tg < ta[j]
    inside = (j > 0) & ((j < len(ta)) | (tg == ta[-1]))
    jc = np.clip(j, 1, len(ta) - 1)
    # Relative to the first stamp: float64 cannot hold epoch stamps' sums exactly.
    span = (ta[jc] - ta[jc - 1]).astype(float)
    keep = inside & ((span <= gap_threshold(ta.astype(float))) | (tg == ta[jc - 1]))
    x, xp = (tg[keep] - ta[0]).astype(float), (ta - ta[0]).astype(float)
    acc = np.stack([np.interp(x, xp, accel[:, k]) for k in range(3)], axis=1)
    left = int(len(tg) - keep.sum())
    apart = float(np.median(np.minimum(np.abs(tg - ta[jc - 1]), np.abs(ta[jc] - tg))))
    notes.append(f"{label}: accelerometer stamps differ from the gyro's (gyro {len(tg)} "
                 f"samples at {_rate(tg, ns_per_unit):.1f} Hz, accelerometer {len(ta)} at "
                 f"{_rate(ta, ns_per_unit):.1f} Hz, median {apart * ns_per_unit / 1e3:.0f} us "
                 "apart); interpolated linearly onto the gyro stamps, never across an "
                 "accelerometer gap"
                 + (f", {left} gyro samples without accelerometer samples around them left out"
                    if left else ""))
    return tg[keep], gyro[keep], acc


def split_rows(gyro: Array, accel: Array) -> tuple[IntArray, IntArray] | None:
    """The rows holding the gyro and those holding the accelerometer, when a table keeps the
    two on different rows (the other sensor's cells empty or NaN): every row has one triple
    complete and the other complete or wholly missing, and some rows have only the gyro and
    some only the accelerometer. None for any other table (its NaNs are then the checks'
    business)."""
    g_ok, a_ok = np.isfinite(gyro).all(axis=1), np.isfinite(accel).all(axis=1)
    g_none, a_none = np.isnan(gyro).all(axis=1), np.isnan(accel).all(axis=1)
    if not (np.all(g_ok | g_none) and np.all(a_ok | a_none) and np.all(g_ok | a_ok)):
        return None
    if not ((g_ok & a_none).any() and (a_ok & g_none).any()):
        return None
    return np.flatnonzero(g_ok), np.flatnonzero(a_ok)


def merge_split_rows(table: ImuTable, notes: list[str]) -> ImuTable:
    """A table whose gyro and accelerometer are on different rows (:func:`split_rows`),
    merged by :func:`merge_on_gyro`; any other table as it is."""
    rows = split_rows(table.gyro, table.accel)
    if rows is None:
        return table
    g, a = rows
    label = table.lines.source
    notes.append(f"{label}: the gyro and the accelerometer are on different rows ({len(g)} "
                 f"and {len(a)} rows)")
    t, gyro, accel = merge_on_gyro(table.ns[g], table.gyro[g], table.ns[a], table.accel[a],
                                   label=label, notes=notes, lines=table.lines.subset(g))
    kept = g[np.searchsorted(table.ns[g], t)]
    return replace(table.take(kept), gyro=gyro, accel=accel)
