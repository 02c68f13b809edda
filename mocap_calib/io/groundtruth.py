"""Ground-truth trajectory files: EuRoC ``state_groundtruth_estimate0/data.csv`` or TUM, plus a
YAML sidecar saying how the trajectory was made.

EuRoC layout (what ``evo_ape euroc`` and the EuRoC tools read): integer ns stamps, position,
quaternion ``w, x, y, z``, velocity, gyro bias, accel bias (SI units). TUM: seconds (exact
decimal from the ns stamps), position, quaternion ``x, y, z, w``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mocap_calib.core.groundtruth.smoother import GroundTruth
from mocap_calib.core.versioned import header
from mocap_calib.errors import InputError
from mocap_calib.io.formats.tum import TUM_HEADER, format_seconds
from mocap_calib.io.tables import write_table
from mocap_calib.io.yaml_io import save_yaml

GT_HEADER = ("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], "
             "q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], "
             "b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], "
             "b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]")
GT_FORMATS = ("euroc", "tum")
REPORT_KIND = "groundtruth_report"
REPORT_VERSION = 1


def sidecar_path(out: Path | str) -> Path:
    """``gt.csv`` -> ``gt.yaml`` (``gt.txt.yaml`` if the output is itself ``.yaml``)."""
    out = Path(out)
    return out.with_name(out.name + ".yaml") if out.suffix == ".yaml" else out.with_suffix(
        ".yaml")


def write_trajectory(out: Path | str, gt: GroundTruth, fmt: str) -> Path:
    """Write the trajectory in ``fmt`` (:data:`GT_FORMATS`); returns its path."""
    if fmt not in GT_FORMATS:
        raise InputError(f"unknown --format '{fmt}'; use euroc or tum")
    q = np.where(gt.quat_wxyz[:, :1] < 0, -gt.quat_wxyz, gt.quat_wxyz)
    try:
        if fmt == "euroc":
            return write_table(out, GT_HEADER, [gt.t_ns, *gt.position.T, *q.T, *gt.velocity.T,
                                                *gt.gyro_bias.T, *gt.accel_bias.T])
        return write_table(out, TUM_HEADER,
                           [format_seconds(gt.t_ns), *gt.position.T, *q[:, [1, 2, 3, 0]].T],
                           sep=" ")
    except OSError as err:
        raise InputError(f"{out}: cannot write ({err.strerror or err}); choose another output "
                         "path") from None


def write_sidecar(out: Path | str, gt: GroundTruth, fmt: str,
                  provenance: dict[str, Any]) -> Path:
    """Write the trajectory's sidecar (:func:`sidecar_path`): how it was made."""
    report = {**header(REPORT_KIND, REPORT_VERSION), "trajectory": str(out), "format": fmt,
              **provenance, **gt.report}
    return save_yaml(sidecar_path(out), report,
                     "mocap-calib ground truth: how the trajectory was made")


def write_groundtruth(out: Path | str, gt: GroundTruth, fmt: str,
                      provenance: dict[str, Any]) -> tuple[Path, Path]:
    """Write the trajectory and its sidecar; returns both paths."""
    path = write_trajectory(out, gt, fmt)
    return path, write_sidecar(path, gt, fmt, provenance)
