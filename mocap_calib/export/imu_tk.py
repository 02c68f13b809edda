"""imu_tk's calibration files (``CalibratedTriad_::save``): for each sensor a text file holding
the misalignment matrix ``T`` (3x3), the scale matrix ``K`` (3x3, diagonal) and the bias vector
``b`` (3 rows), each followed by a blank line, numbers right-aligned to a common width as Eigen
prints a matrix. ``CalibratedTriad_::load`` reads the 21 numbers back in that order, so the
calibrated reading of a raw one is ``T K (raw - b)``.

The numbers are written with full precision (Eigen's stream default would keep 6 digits).
mocap-calib's IMU frame is the accelerometer's orthogonalised frame with the x axis along the
accelerometer's x, so its accelerometer ``T`` is lower-triangular (imu_tk's own is upper
triangular: its frame has z along the accelerometer's z); both are valid for ``load``. The
gyro's g-sensitivity has no place in the format.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.intrinsics.multipos.result import MultiposResult
from mocap_calib.errors import InputError
from mocap_calib.io.yaml_io import save_text

Array = NDArray[np.float64]

#: File suffixes, as imu_tk's example application names its outputs.
SUFFIXES = {"accel": "_acc.calib", "gyro": "_gyro.calib"}


def _block(m: Array) -> str:
    """A matrix (or column vector) as Eigen's default ``operator<<`` lays it out."""
    m = np.atleast_2d(m)
    cells = [[repr(float(v)) for v in row] for row in m]
    width = max(len(c) for row in cells for c in row)
    return "\n".join(" ".join(c.rjust(width) for c in row) for row in cells)


def calib_text(T: Array, K: Array, b: Array) -> str:
    """The text of one ``.calib`` file."""
    return "".join(f"{_block(x)}\n\n" for x in (T, K, np.asarray(b).reshape(3, 1)))


def write_imu_tk(prefix: Path | str, result: MultiposResult, source: str = "the intrinsics"
                 ) -> list[Path]:
    """Write ``PREFIX_acc.calib`` and ``PREFIX_gyro.calib``.

    Returns:
        The two paths.

    Raises:
        InputError: a number to write is not finite (nothing is written).
    """
    forms = result.imu_tk()
    for sensor, form in forms.items():
        for name in ("T", "K", "b"):
            if not np.all(np.isfinite(np.asarray(form[name], dtype=float))):
                raise InputError(f"{source}: imu_tk's {sensor} {name} is "
                                 f"{np.asarray(form[name]).tolist()}, not finite; nothing "
                                 "exported: calibrate again")
    out = []
    for sensor, form in forms.items():
        path = Path(f"{prefix}{SUFFIXES[sensor]}")
        out.append(save_text(path, calib_text(form["T"], form["K"], form["b"])))
    return out


def read_calib(path: Path | str) -> tuple[Array, Array, Array]:
    """``T, K, b`` of a ``.calib`` file, read as ``CalibratedTriad_::load`` does (the first 21
    whitespace-separated numbers, row-major)."""
    v = np.array(Path(path).read_text().split()[:21], dtype=float)
    return v[:9].reshape(3, 3), v[9:18].reshape(3, 3), v[18:21]
