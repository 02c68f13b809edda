"""Options shared by the commands that read a session, and terminal output helpers."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Annotated

import typer

MAV0 = Annotated[Path | None, typer.Argument(
    help="EuRoC/ASL mav0 folder (or its parent) holding imu0/ and vicon0/ "
    "(or state_groundtruth_estimate0/).", show_default=False)]
IMU = Annotated[Path | None, typer.Option(
    "--imu", help="IMU log: CSV (EuRoC imu0/data.csv layout, or generic with --columns), ROS 1 "
    "bag, ROS 2 bag folder (db3 or MCAP), .mcap, or PX4 .ulg.", show_default=False)]
MOCAP = Annotated[Path | None, typer.Option(
    "--mocap", help="Mocap poses T_WM: EuRoC vicon0/data.csv, TUM, generic CSV with --columns, "
    "Motive or Vicon CSV export, a bag/.mcap/.ulg. May be the same file as --imu.",
    show_default=False)]
POSE_SOURCE = Annotated[str, typer.Option(
    help="With a mav0 folder: vicon0, groundtruth, or auto (vicon0 if present).")]
COLUMNS = Annotated[str | None, typer.Option(
    help="Column map of a generic CSV, e.g. 't=0,gyro=1:4,accel=4:7,quat=10:14,pos=14:17' "
    "or a preset name ('broad').", show_default=False)]
TIME_UNIT = Annotated[str | None, typer.Option(
    help="Timestamp unit: s, ms, us or ns (default: the format's own).", show_default=False)]
GYRO_UNIT = Annotated[str | None, typer.Option(help="rad/s or deg/s.", show_default=False)]
ACCEL_UNIT = Annotated[str | None, typer.Option(help="m/s^2 or g.", show_default=False)]
QUAT_ORDER = Annotated[str | None, typer.Option(help="wxyz or xyzw.", show_default=False)]
POSITION_UNIT = Annotated[str | None, typer.Option(help="m, cm or mm.", show_default=False)]
IMU_TOPIC = Annotated[str | None, typer.Option(
    help="Bag/ULog IMU topic (sensor_msgs/Imu; ULog: sensor_combined, or one IMU of several as "
    "sensor_gyro:N or sensor_accel:N). Default: the only one (ULog: sensor_combined).",
    show_default=False)]
MOCAP_TOPIC = Annotated[str | None, typer.Option(
    help="Bag/ULog pose topic (PoseStamped, TransformStamped, PoseWithCovarianceStamped, "
    "Odometry, or /tf with --mocap-frame; ULog: vehicle_mocap_odometry or "
    "vehicle_visual_odometry). Default: the only one.", show_default=False)]
MOCAP_FRAME = Annotated[str | None, typer.Option(
    help="Marker body's frame in a tf2_msgs/TFMessage topic: CHILD (its pose in the root of its "
    "TF tree, /tf_static included) or PARENT:CHILD (in PARENT).", show_default=False)]
STAMP = Annotated[str, typer.Option(
    help="Bag stamps: header (message header.stamp) or receive (the bag's record time).")]
MOCAP_FORMAT = Annotated[str | None, typer.Option(
    help="Mocap export format: motive, vicon-nexus or vicon-tracker (default: detected from "
    "the header).", show_default=False)]
RIGID_BODY = Annotated[str | None, typer.Option(
    help="Rigid body (Motive) or subject (Vicon) to read when the export holds several.",
    show_default=False)]
ROTATION = Annotated[str | None, typer.Option(
    help="Vicon rotations: helical or euler-xyz (R = Rx Ry Rz), optionally :deg or :rad; the "
    "file does not say which.", show_default=False)]
MOCAP_RATE = Annotated[float | None, typer.Option(
    help="Mocap frame rate in Hz, for exports without one (frame numbers only).",
    show_default=False)]
HTML = Annotated[Path | None, typer.Option(
    help="Also write a self-contained HTML report (tables and plots, opens offline in any "
    "browser; render it to a picture with scripts/render_report.sh).", show_default=False)]


class Progress:
    """One line per step on stderr, with the elapsed time (quiet: nothing)."""

    def __init__(self, quiet: bool = False) -> None:
        self.quiet = quiet
        self.t0 = time.perf_counter()

    def __call__(self, message: str) -> None:
        if not self.quiet:
            print(f"[{time.perf_counter() - self.t0:6.1f} s] {message}", file=sys.stderr,
                  flush=True)
