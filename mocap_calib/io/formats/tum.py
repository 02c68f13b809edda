"""TUM trajectories: whitespace-separated ``t x y z qx qy qz qw`` lines, ``#`` comments.

A file of more than 8 columns whose fields 5-8 hold a unit quaternion on every row is a TUM
trajectory with extra columns (velocities, covariances...): its first 8 columns are read and a
note names the others. With a column map for the poses the file is read as a generic CSV.

``t`` is in float seconds. It is parsed digit by digit into integer nanoseconds, and written
from them with 9 decimals, so stamps survive a round trip exactly; positions and quaternions
are written with the shortest exact float representation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocap_calib.core.model.types import MocapPoses
from mocap_calib.errors import InputError, input_error
from mocap_calib.io.formats.generic import indexed_tables
from mocap_calib.io.formats.hints import headerless_euroc_poses
from mocap_calib.io.formats.layout import WHITESPACE, Layout, read_table, sniff_layout
from mocap_calib.io.reading import Format, ReadOptions
from mocap_calib.io.streams import PoseTable
from mocap_calib.io.tables import write_table
from mocap_calib.io.validate import QUAT_NORM_TOL

TUM_HEADER = "# timestamp tx ty tz qx qy qz qw"


def read_tum(path: Path | str, *, time_unit: str = "s", position_unit: str = "m",
             quat_order: str = "xyzw") -> MocapPoses:
    """Read a TUM trajectory as mocap poses ``T_WM``.

    Args:
        path: The file.
        time_unit: Unit of the first column (TUM: s).
        position_unit: m (TUM) or mm.
        quat_order: Order of the last four columns (TUM: xyzw).

    Returns:
        The poses, quaternions ``[w, x, y, z]``; rows with NaN are dropped as occlusions.

    Raises:
        InputError: if rows do not have 8 columns or hold bad values.
    """
    return tum_table(path, time_unit=time_unit, position_unit=position_unit,
                     quat_order=quat_order).validate()


def tum_table(path: Path | str, notes: list[str] | None = None, **kw: str) -> PoseTable:
    """The pose table of a TUM trajectory (arguments of :func:`read_tum`); extra columns are
    named in ``notes``."""
    layout = sniff_layout(path)
    if layout.n_fields < 8 or (layout.n_fields > 8 and not unit_quaternions(layout)):
        raise input_error(f"the first data row has {layout.n_fields} columns; TUM rows have 8 "
                          "(t x y z qx qy qz qw)" + ("" if layout.n_fields < 8 else
                                                     ", or more after a unit quaternion"),
                          "pass a TUM trajectory, or read the file as a generic CSV with "
                          "--columns", layout.source, layout.skip + 1)
    if layout.n_fields > 8 and notes is not None:
        extra = [layout.label(i) for i in range(8, layout.n_fields)]
        notes.append(f"{path}: read as a TUM trajectory (t x y z qx qy qz qw: a unit quaternion "
                     f"in fields 5-8 of every row); ignored its other column"
                     f"{'s' if len(extra) > 1 else ''} {', '.join(extra)} (--mocap-columns reads "
                     "others)")
    _, mocap = indexed_tables(layout, time=0, position=(1, 2, 3), quat=(4, 5, 6, 7),
                              **{"time_unit": "s", "position_unit": "m", "quat_order": "xyzw",
                                 **kw})
    assert mocap is not None
    return mocap


def unit_quaternions(layout: Layout) -> bool:
    """True when fields 5-8 (0-based 4-7) of every data row are a unit quaternion (NaN rows,
    occlusions, aside): what tells a TUM trajectory with extra columns from another table."""
    try:
        table = read_table(layout, [4, 5, 6, 7], 0)
    except InputError:
        return False
    if table.bad:
        return False
    q = np.stack([table.numbers[i] for i in (4, 5, 6, 7)], axis=1)
    q = q[~np.isnan(q).any(axis=1)]
    return len(q) > 0 and bool(np.all(np.abs(np.linalg.norm(q, axis=1) - 1.0) <= QUAT_NORM_TOL))


def format_seconds(ns: np.ndarray) -> list[str]:
    """Integer nanoseconds as exact decimal seconds with 9 decimals (``-1.500000000``)."""
    ns = np.asarray(ns, dtype=np.int64)
    a = np.abs(ns)
    sign = np.where(ns < 0, "-", "").tolist()
    return list(map("{}{}.{:09d}".format, sign, (a // 1_000_000_000).tolist(),
                    (a % 1_000_000_000).tolist()))


def write_tum(path: Path | str, mocap: MocapPoses) -> Path:
    """Write poses as a TUM trajectory (quaternions ``xyzw`` with ``w >= 0``).

    Args:
        path: Output file; parent folders are created.
        mocap: The poses ``T_WM``.

    Returns:
        The path written.
    """
    q = mocap.quat_wxyz
    q = np.where(q[:, :1] < 0, -q, q)
    return write_table(path, TUM_HEADER,
                       [format_seconds(mocap.stamps_ns()), *mocap.position.T,
                        q[:, 1], q[:, 2], q[:, 3], q[:, 0]], sep=" ")


# --- the registry's record -------------------------------------------------------------------

def _is_tum(path: Path) -> bool:
    try:
        layout = sniff_layout(path)
    except InputError:
        return False
    return layout.sep == WHITESPACE and (layout.n_fields == 8 or (
        layout.n_fields > 8 and unit_quaternions(layout)))


def _poses(path: Path, opts: ReadOptions, notes: list[str]) -> PoseTable:
    if opts.time_unit is None and (euroc := headerless_euroc_poses(path)) is not None:
        raise euroc
    return tum_table(path, notes, **opts.units("time_unit", "quat_order", "position_unit"))


FORMAT = Format("tum", "TUM trajectory", _is_tum, read_poses=_poses,
                options=frozenset({"time_unit", "quat_order", "position_unit"}),
                yields_to_columns=True)
