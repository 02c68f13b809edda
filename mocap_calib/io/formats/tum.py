"""TUM trajectories: whitespace-separated ``t x y z qx qy qz qw`` lines, ``#`` comments.

``t`` is in float seconds. It is parsed digit by digit into integer nanoseconds, and written
from them with 9 decimals, so stamps survive a round trip exactly; positions and quaternions
are written with the shortest exact float representation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocap_calib.core.model.types import MocapPoses
from mocap_calib.errors import input_error
from mocap_calib.io.formats.generic import read_indexed
from mocap_calib.io.formats.layout import sniff_layout
from mocap_calib.io.tables import write_table

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
    layout = sniff_layout(path)
    if layout.n_fields != 8:
        raise input_error(f"the first data row has {layout.n_fields} columns; TUM rows have 8 "
                          "(t x y z qx qy qz qw)", "pass a TUM trajectory, or read the file as a "
                          "generic CSV with --columns", layout.source, layout.skip + 1)
    _, mocap = read_indexed(layout, time=0, position=(1, 2, 3), quat=(4, 5, 6, 7),
                            time_unit=time_unit, position_unit=position_unit,
                            quat_order=quat_order)
    assert mocap is not None
    return mocap


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
