"""EuRoC/ASL files: ``imu0/data.csv``, ``vicon0/data.csv``, ``state_groundtruth_estimate0``.

Layouts are those of ``docs/conventions.md``: integer nanosecond stamps, rad/s, m/s^2, metres,
quaternions ``[w, x, y, z]``. Header names are matched loosely (leading ``#``, spaces and the
bracketed unit are ignored), so ``#timestamp`` and ``#timestamp [ns]`` both work and extra
columns after the first 7 (IMU) or 8 (poses) are ignored. The unit keywords of the readers
exist for files that follow the layout but not its units; by default they are the EuRoC units.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from mocap_calib.core.model.types import ImuSamples, MocapPoses
from mocap_calib.errors import InputError, input_error
from mocap_calib.io.formats.columns import (
    IMU_HEADER,
    IMU_KEYS,
    IMU_NAMES,
    POSE_HEADER,
    POSE_KEYS,
    POSE_NAMES,
    name_key,
)
from mocap_calib.io.formats.generic import generic_tables, indexed_tables
from mocap_calib.io.formats.layout import Layout, sniff_layout
from mocap_calib.io.reading import UNIT_OPTIONS, Format, ReadOptions, Stream
from mocap_calib.io.streams import ImuTable, PoseTable
from mocap_calib.io.tables import write_table

#: ``pose_source`` value -> folder under ``mav0``; "auto" tries them in this order.
POSE_FOLDERS: dict[str, str] = {"vicon0": "vicon0", "groundtruth": "state_groundtruth_estimate0"}


def header_kind(names: Sequence[str] | None) -> str | None:
    """``"imu"`` or ``"poses"`` if a header starts with that EuRoC layout's names, else None."""
    if names is None:
        return None
    keys = tuple(name_key(n) for n in names)
    if keys[: len(IMU_KEYS)] == IMU_KEYS:
        return "imu"
    if keys[: len(POSE_KEYS)] == POSE_KEYS:
        return "poses"
    return None


def _check_header(layout: Layout, kind: str) -> None:
    """Raise naming the first column that does not match the EuRoC layout ``kind``."""
    keys, names, what = ((IMU_KEYS, IMU_NAMES, "imu0") if kind == "imu"
                         else (POSE_KEYS, POSE_NAMES, "pose (vicon0)"))
    other = header_kind(layout.names)
    if other is not None and other != kind:
        flag = "--imu" if other == "imu" else "--mocap"
        raise input_error(f"this is an EuRoC {'IMU' if other == 'imu' else 'pose'} file, "
                          f"not an EuRoC {what} file", f"pass it with {flag}",
                          layout.source, layout.header_line)
    fix = (f"use the EuRoC {what} header of docs/conventions.md, or read the file as a generic "
           "CSV with --columns")
    if layout.names is None:
        raise input_error(f"no header line (expected the EuRoC {what} header starting "
                          f"'{IMU_HEADER[:30] if kind == 'imu' else POSE_HEADER[:30]}...')",
                          fix, layout.source, layout.skip + 1)
    for i, (key, name) in enumerate(zip(keys, names, strict=True)):
        if i >= len(layout.names):
            raise input_error(f"column {i + 1} '{name}' is missing from the header "
                              f"(EuRoC {what} has {len(keys)} columns)", fix, layout.source,
                              layout.header_line)
        if name_key(layout.names[i]) != key:
            raise input_error(f"column {i + 1} is '{layout.names[i]}' but the EuRoC {what} "
                              f"layout expects '{name}'", fix, layout.source, layout.header_line)
    if layout.n_fields < len(keys):
        raise input_error(f"the first data row has {layout.n_fields} columns; EuRoC {what} "
                          f"rows have {len(keys)} (missing '{names[layout.n_fields]}')",
                          "write every column of the header on every row", layout.source,
                          layout.skip + 1)


def read_euroc_imu(path: Path | str, *, time_unit: str = "ns", gyro_unit: str = "rad/s",
                   accel_unit: str = "m/s^2", raw: bool = False) -> ImuSamples:
    """Read an EuRoC ``imu0/data.csv``.

    Args:
        path: The CSV file.
        time_unit: Unit of the stamps (EuRoC: ns).
        gyro_unit: rad/s (EuRoC) or deg/s.
        accel_unit: m/s^2 (EuRoC) or g.
        raw: the readings are raw counts (no unit conversion or check).

    Returns:
        The IMU samples.

    Raises:
        InputError: on a wrong header or bad rows (one line naming the file, line and fix).
    """
    return euroc_imu_table(path, time_unit=time_unit, gyro_unit=gyro_unit,
                           accel_unit=accel_unit, raw=raw).validate()


def euroc_imu_table(path: Path | str, **kw: Any) -> ImuTable:
    """The IMU table of an EuRoC ``imu0/data.csv`` (arguments of :func:`read_euroc_imu`)."""
    layout = sniff_layout(path)
    _check_header(layout, "imu")
    imu, _ = indexed_tables(layout, time=0, gyro=(1, 2, 3), accel=(4, 5, 6),
                            **{"time_unit": "ns", **kw})
    assert imu is not None
    return imu


def read_euroc_poses(path: Path | str, *, time_unit: str = "ns", position_unit: str = "m",
                     quat_order: str = "wxyz") -> MocapPoses:
    """Read EuRoC poses: ``vicon0/data.csv`` or ``state_groundtruth_estimate0/data.csv``.

    Only the first 8 columns (stamp, position, quaternion) are read; the ground truth's
    velocity and bias columns are ignored. Rows with NaN are dropped as occlusions.

    Args:
        path: The CSV file.
        time_unit: Unit of the stamps (EuRoC: ns).
        position_unit: m (EuRoC), cm or mm.
        quat_order: wxyz (EuRoC) or xyzw.

    Returns:
        The poses ``T_WM``.

    Raises:
        InputError: on a wrong header or bad rows.
    """
    return euroc_pose_table(path, time_unit=time_unit, position_unit=position_unit,
                            quat_order=quat_order).validate()


def euroc_pose_table(path: Path | str, **kw: Any) -> PoseTable:
    """The pose table of an EuRoC pose CSV (arguments of :func:`read_euroc_poses`)."""
    layout = sniff_layout(path)
    _check_header(layout, "poses")
    _, mocap = indexed_tables(layout, time=0, quat=(4, 5, 6, 7), position=(1, 2, 3),
                              **{"time_unit": "ns", **kw})
    assert mocap is not None
    return mocap


@dataclass(frozen=True)
class Mav0:
    """An EuRoC ``mav0`` session.

    Attributes:
        imu: ``imu0`` samples.
        mocap: Poses from ``pose_source``.
        pose_source: ``"vicon0"`` (raw marker poses ``T_WM``) or ``"groundtruth"``
            (``state_groundtruth_estimate0``: fused poses of the body (IMU) frame itself).
        T_imu_marker: 4x4 ``T_IM`` from ``T_BS`` of the pose folder's ``sensor.yaml``, or None
            if there is none. For ``vicon0`` this is the published marker pose in the IMU frame
            (``T_MI = inv(T_IM)``); for ``groundtruth`` EuRoC's file gives the identity,
            because those poses are of the IMU frame.
        root: The ``mav0`` folder.
    """

    imu: ImuSamples
    mocap: MocapPoses
    pose_source: str
    T_imu_marker: NDArray[np.float64] | None
    root: Path


def find_mav0(path: Path | str) -> Path:
    """The ``mav0`` folder: ``path`` itself or ``path/mav0`` (whichever holds ``imu0/``).

    Raises:
        InputError: if neither does.
    """
    path = Path(path)
    for root in (path, path / "mav0"):
        if (root / "imu0" / "data.csv").is_file():
            return root
    if not path.exists():
        raise input_error("folder not found", "check the path", str(path))
    raise input_error("no EuRoC mav0 folder here (no imu0/data.csv in it or in mav0/)",
                      "pass the mav0 folder or the folder that contains it", str(path))


def read_t_bs(path: Path | str) -> NDArray[np.float64] | None:
    """The 4x4 ``T_BS`` of an EuRoC ``sensor.yaml``, or None if the file or key is absent.

    Raises:
        InputError: if ``T_BS`` is present but not a 4x4 matrix.
    """
    path = Path(path)
    if not path.is_file():
        return None
    # OpenCV-style files start with "%YAML:1.0", which PyYAML rejects.
    text = "".join(ln for ln in path.read_text(encoding="utf-8", errors="replace")
                   .splitlines(keepends=True) if not ln.startswith("%YAML"))
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise input_error(f"not valid YAML ({str(err).splitlines()[0]})",
                          "fix or delete the file", str(path)) from None
    if not isinstance(doc, dict) or doc.get("T_BS") is None:
        return None
    tbs = doc["T_BS"]
    data = tbs.get("data") if isinstance(tbs, dict) else tbs
    try:
        T = np.asarray(data, dtype=np.float64).reshape(4, 4)
    except (TypeError, ValueError):
        raise input_error("T_BS is not a 4x4 matrix", "give T_BS as {rows: 4, cols: 4, "
                          "data: [16 numbers]} or delete it", str(path)) from None
    return T


def pose_folder(root: Path, pose_source: str = "auto") -> tuple[str, Path]:
    """The pose source to use in a ``mav0`` folder and its folder.

    Args:
        root: The ``mav0`` folder.
        pose_source: ``"auto"`` (vicon0 if present, else the ground truth), ``"vicon0"`` or
            ``"groundtruth"``.

    Returns:
        (pose source name, its folder).

    Raises:
        InputError: on an unknown name or when the folder has no ``data.csv``.
    """
    if pose_source not in ("auto", *POSE_FOLDERS):
        raise input_error(f"unknown --pose-source {pose_source!r}",
                          "use auto, vicon0 or groundtruth")
    candidates = list(POSE_FOLDERS) if pose_source == "auto" else [pose_source]
    for name in candidates:
        if (root / POSE_FOLDERS[name] / "data.csv").is_file():
            return name, root / POSE_FOLDERS[name]
    wanted = " or ".join(f"{POSE_FOLDERS[c]}/data.csv" for c in candidates)
    raise input_error(f"no {wanted} in the mav0 folder",
                      "pass --pose-source for a pose folder that exists, or pass the poses "
                      "with --mocap", str(root))


def read_mav0(path: Path | str, pose_source: str = "auto", *, time_unit: str = "ns",
              gyro_unit: str = "rad/s", accel_unit: str = "m/s^2", quat_order: str = "wxyz",
              position_unit: str = "m") -> Mav0:
    """Read an EuRoC ``mav0`` folder: IMU, poses and the published marker extrinsics.

    Args:
        path: The ``mav0`` folder or its parent.
        pose_source: ``"vicon0"``, ``"groundtruth"`` (``state_groundtruth_estimate0``) or
            ``"auto"`` (vicon0 if present, else the ground truth).
        time_unit: Unit of both files' stamps (EuRoC: ns).
        gyro_unit: rad/s (EuRoC) or deg/s.
        accel_unit: m/s^2 (EuRoC) or g.
        quat_order: wxyz (EuRoC) or xyzw.
        position_unit: m (EuRoC), cm or mm.

    Returns:
        The session.

    Raises:
        InputError: if the folder, a file or the pose source is missing or bad.
    """
    root = find_mav0(path)
    chosen, folder = pose_folder(root, pose_source)
    imu = read_euroc_imu(root / "imu0" / "data.csv", time_unit=time_unit, gyro_unit=gyro_unit,
                         accel_unit=accel_unit)
    mocap = read_euroc_poses(folder / "data.csv", time_unit=time_unit,
                             position_unit=position_unit, quat_order=quat_order)
    return Mav0(imu, mocap, chosen, read_t_bs(folder / "sensor.yaml"), root)


def _canonical(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """Quaternions with ``w >= 0`` (the project's written form; negation is exact)."""
    return np.where(q[:, :1] < 0, -q, q)


def write_euroc_imu(path: Path | str, imu: ImuSamples) -> Path:
    """Write IMU samples as an EuRoC ``imu0/data.csv`` (exact: reading back is bit-identical).

    Args:
        path: Output file; parent folders are created.
        imu: The samples.

    Returns:
        The path written.
    """
    return write_table(path, IMU_HEADER, [imu.stamps_ns(), *imu.gyro.T, *imu.accel.T])


def write_euroc_poses(path: Path | str, mocap: MocapPoses) -> Path:
    """Write poses as an EuRoC ``vicon0/data.csv`` (quaternions with ``w >= 0``).

    Args:
        path: Output file; parent folders are created.
        mocap: The poses ``T_WM``.

    Returns:
        The path written.
    """
    q = _canonical(mocap.quat_wxyz)
    return write_table(path, POSE_HEADER, [mocap.stamps_ns(), *mocap.position.T, *q.T])


def write_mav0(folder: Path | str, imu: ImuSamples, mocap: MocapPoses) -> Path:
    """Write ``folder/mav0/imu0/data.csv`` and ``folder/mav0/vicon0/data.csv``.

    Args:
        folder: Folder to create ``mav0`` in.
        imu: The IMU samples.
        mocap: The poses ``T_WM``.

    Returns:
        The ``mav0`` folder.
    """
    root = Path(folder) / "mav0"
    write_euroc_imu(root / "imu0" / "data.csv", imu)
    write_euroc_poses(root / "vicon0" / "data.csv", mocap)
    return root


# --- the registry's records ------------------------------------------------------------------

def _imu_file(path: Path, opts: ReadOptions, notes: list[str]) -> ImuTable:
    """An EuRoC IMU CSV, read as the column map says when it names the IMU's columns
    (EuRoC's units stay the defaults)."""
    kw: dict[str, Any] = {"time_unit": "ns", "raw": opts.raw,
                          **opts.units("time_unit", "gyro_unit", "accel_unit")}
    cmap = opts.imu_columns
    if cmap is None or not cmap.has_imu:
        return euroc_imu_table(path, **kw)
    flag = opts.columns_flag(Stream.IMU)
    imu, _ = generic_tables(path, cmap, streams=["imu"], flag=flag, **kw)
    assert imu is not None
    notes.append(f"read {path} with the {flag} map")
    return imu


def _pose_file(path: Path, opts: ReadOptions, notes: list[str]) -> PoseTable:
    """An EuRoC pose CSV, read as the column map says when it names the poses' columns."""
    kw: dict[str, Any] = {"time_unit": "ns",
                          **opts.units("time_unit", "quat_order", "position_unit")}
    cmap = opts.mocap_columns
    if cmap is None or not cmap.has_mocap:
        return euroc_pose_table(path, **kw)
    flag = opts.columns_flag(Stream.POSES)
    _, poses = generic_tables(path, cmap, streams=["mocap"], flag=flag, **kw)
    assert poses is not None
    notes.append(f"read {path} with the {flag} map")
    return poses


def _mav0_imu(path: Path, opts: ReadOptions, notes: list[str]) -> ImuTable:
    file = find_mav0(path) / "imu0" / "data.csv"
    return replace(_imu_file(file, opts, notes), file=str(file))


def _mav0_poses(path: Path, opts: ReadOptions, notes: list[str]) -> PoseTable:
    name, folder = pose_folder(find_mav0(path), opts.pose_source)
    read_t_bs(folder / "sensor.yaml")  # a malformed T_BS is refused here, as by read_mav0
    notes.append(f"poses from {folder}")
    if name == "groundtruth":
        notes.append("ground-truth poses are of the IMU (body) frame, not of the marker body")
    return replace(_pose_file(folder / "data.csv", opts, notes), file=str(folder / "data.csv"))


def _header_is(path: Path, kind: str) -> bool:
    try:
        return header_kind(sniff_layout(path).names) == kind
    except InputError:
        return False


_TEXT = frozenset({"columns", *UNIT_OPTIONS, "raw"})
MAV0 = Format("mav0", "EuRoC mav0 folder", Path.is_dir, _mav0_imu, _mav0_poses,
              options=_TEXT | {"pose_source"})
EUROC_IMU = Format("euroc_imu", "EuRoC IMU CSV", lambda p: _header_is(p, "imu"), _imu_file,
                   options=_TEXT)
EUROC_POSES = Format("euroc_poses", "EuRoC pose CSV", lambda p: _header_is(p, "poses"),
                     read_poses=_pose_file, options=_TEXT)
