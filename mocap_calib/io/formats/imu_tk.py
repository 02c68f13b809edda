"""imu_tk's input layout: two whitespace-separated text files, one for the accelerometer and one
for the gyroscope, each ``t x y z`` per line (imu_tk's ``importAsciiData``; its example reads the
stamps in seconds).

The two streams may share their stamps or not. If not, the accelerometer is merged onto the
gyro's stamps by the shared step (:mod:`mocap_calib.io.merge`: linear interpolation between
neighbours, never across an accelerometer gap, never extrapolated).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.types import ImuSamples
from mocap_calib.core.policy import ACCEL_UNITS, GYRO_UNITS
from mocap_calib.errors import input_error
from mocap_calib.io.formats.layout import numeric_column, read_table, sniff_layout
from mocap_calib.io.formats.stamps import parse_stamps
from mocap_calib.io.merge import merge_on_gyro
from mocap_calib.io.streams import ImuTable
from mocap_calib.io.validate import TIME_UNITS, Lines, check_increasing, check_unit

Array = NDArray[np.float64]
IntArray = NDArray[np.int64]


def read_triad(path: Path | str, time_unit: str = "s") -> tuple[IntArray, Array, Lines]:
    """One imu_tk file: integer nanosecond stamps, (N, 3) values, and its line map.

    Raises:
        InputError: missing file, fewer than 4 columns, non-numbers, stamps not increasing.
    """
    layout = sniff_layout(path)
    if layout.n_fields < 4:
        raise input_error(f"has {layout.n_fields} columns, not imu_tk's 't x y z'",
                          "pass an imu_tk data file (timestamp and three values per line)",
                          layout.source, layout.skip + 1)
    table = read_table(layout, [0, 1, 2, 3], 0)
    lines = layout.lines()
    ns = parse_stamps(table.text[0], time_unit, layout.label(0), lines, layout.decimal)
    xyz = np.stack([numeric_column(table, c, layout, lines) for c in (1, 2, 3)], axis=1)
    bad = ~np.isfinite(xyz).all(axis=1)
    if bad.any():
        raise lines.error("row has a NaN, infinite or missing value", "fix or delete that row",
                          int(np.flatnonzero(bad)[0]))
    check_increasing(ns, "IMU", lines)
    return ns, xyz, lines


def read_imu_tk_pair(accel_path: Path | str, gyro_path: Path | str, *, time_unit: str = "s",
                     gyro_unit: str = "rad/s", accel_unit: str = "m/s^2", raw: bool = False
                     ) -> tuple[ImuSamples, list[str]]:
    """The checked samples of :func:`imu_tk_pair_table` and its notes."""
    notes: list[str] = []
    table = imu_tk_pair_table(accel_path, gyro_path, notes, time_unit=time_unit,
                              gyro_unit=gyro_unit, accel_unit=accel_unit, raw=raw)
    return table.validate(), notes


def imu_tk_pair_table(accel_path: Path | str, gyro_path: Path | str, notes: list[str], *,
                      time_unit: str = "s", gyro_unit: str = "rad/s",
                      accel_unit: str = "m/s^2", raw: bool = False) -> ImuTable:
    """Read imu_tk's two files as one IMU stream on the gyro's stamps (the shared merge step,
    :func:`~mocap_calib.io.merge.merge_on_gyro`).

    Args:
        accel_path: accelerometer file (``t ax ay az``).
        gyro_path: gyroscope file (``t gx gy gz``).
        notes: Where the notes go.
        time_unit: unit of the stamps (imu_tk's example: s).
        gyro_unit: rad/s or deg/s (ignored with ``raw``).
        accel_unit: m/s^2 or g (ignored with ``raw``).
        raw: the values are raw counts (no conversion or unit check).

    Returns:
        The IMU table (``file`` names both files).

    Raises:
        InputError: a bad file, or files that do not overlap in time.
    """
    check_unit(time_unit, TIME_UNITS, "--time-unit")
    check_unit(gyro_unit, GYRO_UNITS, "--gyro-unit")
    check_unit(accel_unit, ACCEL_UNITS, "--accel-unit")
    ns_a, acc, _ = read_triad(accel_path, time_unit)
    ns_g, gyr, lines = read_triad(gyro_path, time_unit)
    if len(ns_a) == len(ns_g) and np.array_equal(ns_a, ns_g):
        notes.append("accelerometer and gyro files share their stamps")
    elif ((ns_g >= ns_a[0]) & (ns_g <= ns_a[-1])).sum() < 2:
        raise input_error("the accelerometer and gyro files do not overlap in time",
                          "pass the two files of one recording (check --time-unit)",
                          f"{accel_path}, {gyro_path}")
    else:
        kept, gyr, acc = merge_on_gyro(ns_g, gyr, ns_a, acc, label=f"{accel_path}, {gyro_path}",
                                       notes=notes, lines=lines)
        rows = np.searchsorted(ns_g, kept)
        ns_g, lines = kept, lines.subset(rows)
    if not raw:
        gyr = gyr * GYRO_UNITS[gyro_unit]
        acc = acc * ACCEL_UNITS[accel_unit]
    return ImuTable(ns_g, gyr, acc, lines, time_unit=time_unit, gyro_unit=gyro_unit,
                    accel_unit=accel_unit, raw=raw, file=f"{accel_path}, {gyro_path}")
