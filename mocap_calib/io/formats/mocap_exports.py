"""Mocap exports: OptiTrack Motive CSV, Vicon Nexus CSV and Vicon Tracker CSV.

**Motive** (format 1.2x and later): line 1 holds metadata as key/value cells (``Capture Frame
Rate``, ``Export Frame Rate``, ``Rotation Type``, ``Length Units``, ``Capture Start Time``...);
then the Type, Name, ID (and Parent) rows, the Rotation/Position row and the
``Frame,Time (Seconds),X,Y,Z,W,X,Y,Z`` row. Rigid-body rotations must be quaternions (x, y, z,
w columns); an export with Euler angles is refused because Motive's Euler orders are not
recoverable from the file. Occluded frames are empty cells (dropped and counted). Motive's
world is y-up: it is kept as the mocap world ``W`` (the calibration estimates the gravity
direction in any orientation, so ``gravity_in_mocap`` is then near -y). Stamps are the frame
number over the export frame rate, from the capture start time (read as UTC: Motive writes
local time without a zone, so the clock offset search aligns it with the IMU).

**Vicon Nexus** (``Segments``/``Model Outputs`` section) and **Vicon Tracker** (``Objects``):
line 1 the section, line 2 the frame rate, line 3 the subject names, then
``Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ`` per subject and a units row. Positions are in the
units row's unit (mm); rotations are helical (rotation vector) or XYZ Euler angles depending on
the export settings, which the file does not record: ``rotation`` says which (``helical`` or
``euler-xyz``, with ``:deg``/``:rad`` if the units row does not say). ``euler-xyz`` means
``R_WM = Rx(RX) Ry(RY) Rz(RZ)``. Without a frame rate in the file the stamps are frame numbers
only: ``rate_hz`` must be given, and the clock offset to the IMU is then left to the clock
search. Stamps start at 0 at frame 0.
"""

from __future__ import annotations

import csv
import re
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from mocap_calib.core.model import so3
from mocap_calib.core.model.types import MocapPoses
from mocap_calib.errors import InputError, input_error
from mocap_calib.io.formats.layout import data_lines, parse_rows
from mocap_calib.io.reading import ExportOptions, Format, ReadOptions
from mocap_calib.io.streams import PoseTable
from mocap_calib.io.validate import Lines

__all__ = ["ExportOptions", "read_export", "sniff_export"]  # ExportOptions re-exported

EXPORT_FORMATS = ("motive", "vicon-nexus", "vicon-tracker")
ROTATIONS = ("helical", "euler-xyz")
_NEXUS_SECTIONS = ("segments", "model outputs", "joints", "trajectories")
_LENGTH = {"meters": 1.0, "centimeters": 1e-2, "millimeters": 1e-3, "m": 1.0, "cm": 1e-2,
           "mm": 1e-3}


def sniff_export(path: Path | str) -> str | None:
    """The export format from the first line, or None if the file is no mocap export."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as f:
            first = f.readline()
    except OSError:
        return None
    cell = first.split(",")[0].strip().strip('"').lower()
    if cell == "format version":
        return "motive"
    if cell in _NEXUS_SECTIONS:
        return "vicon-nexus"
    if cell == "objects":
        return "vicon-tracker"
    return None


def read_export(path: Path | str, opts: ExportOptions, notes: list[str]) -> MocapPoses:
    """The checked poses of a Motive or Vicon export (:func:`export_table`)."""
    return export_table(path, opts, notes).validate()


def export_table(path: Path | str, opts: ExportOptions, notes: list[str]) -> PoseTable:
    """Read a Motive or Vicon export (the format from ``opts`` or the file's first line)."""
    path = Path(path)
    if not path.is_file():
        raise input_error("file not found", "check the path", str(path))
    fmt = opts.mocap_format or sniff_export(path)
    if fmt not in EXPORT_FORMATS:
        raise input_error(f"unknown --mocap-format '{fmt}'" if fmt else
                          "not a Motive or Vicon export (its first line is neither Motive's "
                          "metadata nor a Vicon section name)",
                          f"use one of: {', '.join(EXPORT_FORMATS)}", str(path))
    with open(path, encoding="utf-8-sig", errors="replace", newline="") as f:
        head = [row for _, row in zip(range(12), csv.reader(f), strict=False)]
    if fmt == "motive":
        return _read_motive(path, head, opts, notes)
    return _read_vicon(path, head, fmt, opts, notes)


def _pick_body(names: list[str], wanted: str | None, path: Path, noun: str) -> str:
    if not names:
        raise input_error(f"no {noun} with a pose (rotation and position) in the file",
                          f"export the {noun} data (not only markers)", str(path))
    if wanted is None:
        if len(names) == 1:
            return names[0]
        raise input_error(f"the file holds {len(names)} {noun}s: {', '.join(names)}",
                          "choose one with --rigid-body NAME", str(path))
    for n in names:
        if wanted in (n, n.split(":")[-1]):
            return n
    raise input_error(f"no {noun} '{wanted}' in the file ({noun}s: {', '.join(names)})",
                      "pass --rigid-body with one of those", str(path))


def _numbers(path: Path, skip: int, cols: list[int]) -> dict[int, np.ndarray]:
    """Columns ``cols`` of the data rows, as floats (empty cells are NaN)."""
    table = parse_rows(data_lines(path, skip), ",", max(cols) + 1, cols, ragged_ok=True)
    if table.bad:
        c = min(table.bad, key=lambda k: table.bad[k][0])
        r, cell = table.bad[c]
        raise input_error(f"line {skip + r + 1}: '{cell}' is not a number",
                          "fix or delete that row", str(path))
    return table.numbers


def _stamps_from_frames(frames: np.ndarray, rate: float) -> np.ndarray:
    return np.round(frames * (1e9 / rate)).astype(np.int64)


# --- Motive ----------------------------------------------------------------------------------

def _motive_meta(row: list[str]) -> dict[str, str]:
    return {row[i].strip().lower(): row[i + 1].strip() for i in range(0, len(row) - 1, 2)}


def _capture_start_ns(meta: dict[str, str], notes: list[str], label: str) -> int:
    text = meta.get("capture start time", "")
    for fmt in ("%Y-%m-%d %I.%M.%S.%f %p", "%Y-%m-%d %H.%M.%S.%f", "%Y-%m-%d %I.%M.%S %p"):
        try:
            start = datetime.strptime(text, fmt).replace(tzinfo=UTC)
            return (start - datetime(1970, 1, 1, tzinfo=UTC)) // timedelta(microseconds=1) * 1000
        except ValueError:
            continue
    notes.append(f"{label}: no readable Capture Start Time; stamps start at 0")
    return 0


def _read_motive(path: Path, head: list[list[str]], opts: ExportOptions,
                 notes: list[str]) -> PoseTable:
    meta = _motive_meta(head[0])
    rot = meta.get("rotation type", "Quaternion")
    if rot.lower() != "quaternion":
        raise input_error(f"rotations are exported as '{rot}' Euler angles, whose order the "
                          "file does not pin down", "re-export from Motive with Rotation Type "
                          "set to Quaternion", str(path))
    unit = meta.get("length units", "Meters")
    if unit.lower() not in _LENGTH:
        raise input_error(f"unknown Length Units '{unit}'", "re-export in meters or "
                          "millimeters", str(path))
    axis_i = next((i for i, r in enumerate(head) if r and r[0].strip() == "Frame"), None)
    if axis_i is None or axis_i < 3:
        raise input_error("no 'Frame,Time (Seconds),...' header row", "export the take with "
                          "Motive's CSV header enabled", str(path))
    axis, comp = head[axis_i], head[axis_i - 1]
    labelled = {r[1].strip().lower(): r for r in head[1:axis_i - 1] if len(r) > 1}
    types = labelled.get("type", head[2])
    names = labelled.get("name", head[3])
    bodies: dict[str, dict[str, int]] = {}
    for j in range(2, len(axis)):
        if j >= len(types) or types[j].strip() != "Rigid Body":
            continue
        key = f"{comp[j].strip().lower()}_{axis[j].strip().lower()}"
        bodies.setdefault(names[j].strip(), {})[key] = j
    need = ("rotation_x", "rotation_y", "rotation_z", "rotation_w", "position_x", "position_y",
            "position_z")
    complete = [n for n, c in bodies.items() if all(k in c for k in need)]
    name = _pick_body(complete, opts.rigid_body, path, "rigid body")
    cols = bodies[name]
    time_j = next((j for j, a in enumerate(axis) if a.strip().lower().startswith("time")), None)
    rate = opts.mocap_rate
    for key in ("export frame rate", "capture frame rate"):
        if rate is None and meta.get(key):
            rate = float(meta[key])
    used = [0, *([time_j] if time_j is not None else []), *(cols[k] for k in need)]
    data = _numbers(path, axis_i + 1, sorted(set(used)))
    label = f"{path} [{name}]"
    if rate is not None and rate > 0:
        ns = _stamps_from_frames(data[0], rate)
    elif time_j is not None:
        ns = np.round(data[time_j] * 1e9).astype(np.int64)
    else:
        raise input_error("no frame rate and no time column in the file (frame numbers only)",
                          "pass --mocap-rate HZ (the clock offset to the IMU is then found by "
                          "the clock search)", str(path))
    q_xyzw = np.stack([data[cols[k]] for k in need[:4]], axis=1)
    p = np.stack([data[cols[k]] for k in need[4:]], axis=1) * _LENGTH[unit.lower()]
    origin = _capture_start_ns(meta, notes, label)
    notes.append(f"{label}: Motive export, {unit.lower()}, y-up world kept as the mocap world")
    return PoseTable(ns + origin, np.ascontiguousarray(q_xyzw[:, [3, 0, 1, 2]]), p,
                     Lines(label, path, skip=axis_i + 1, comment=None))


# --- Vicon -----------------------------------------------------------------------------------

def _parse_rotation(spec: str | None, unit_cell: str, path: Path) -> tuple[str, float]:
    if spec is None:
        raise input_error("Vicon CSV files do not say whether rotations are helical or Euler "
                          "angles", "pass --rotation helical or --rotation euler-xyz (as set "
                          "in the export)", str(path))
    form, _, unit = spec.partition(":")
    if form not in ROTATIONS or unit not in ("", "deg", "rad"):
        raise InputError(f"unknown --rotation '{spec}'; use helical or euler-xyz, optionally "
                         "with :deg or :rad")
    unit = unit or unit_cell.strip().lower()
    if unit not in ("deg", "rad"):
        raise input_error("the units row does not give the rotation unit",
                          f"pass --rotation {form}:deg or --rotation {form}:rad", str(path))
    return form, (np.pi / 180.0 if unit == "deg" else 1.0)


def _vicon_rotation(r: np.ndarray, form: str) -> np.ndarray:
    """(N, 3, 3) ``R_WM`` from helical vectors or XYZ Euler angles (rad); NaN rows stay NaN."""
    ok = np.isfinite(r).all(axis=1)
    r0 = np.where(ok[:, None], r, 0.0)
    if form == "helical":
        R = so3.exp(r0)
    else:
        R = so3.exp(r0[:, 0, None] * np.eye(3)[0]) @ so3.exp(r0[:, 1, None] * np.eye(3)[1]) \
            @ so3.exp(r0[:, 2, None] * np.eye(3)[2])
    R[~ok] = np.nan
    return R


def _read_vicon(path: Path, head: list[list[str]], fmt: str, opts: ExportOptions,
                notes: list[str]) -> PoseTable:
    if len(head) < 5:
        raise input_error("fewer than 5 header lines (section, rate, names, columns, units)",
                          "export the whole take from Vicon as CSV", str(path))
    section = head[0][0].strip() if head[0] else ""
    cols, units = head[3], head[4]
    groups = [j for j in range(len(cols) - 5) if [c.strip().upper() for c in cols[j:j + 6]]
              == ["RX", "RY", "RZ", "TX", "TY", "TZ"]]
    names_row = head[2]
    names = []
    for j in groups:
        raw = names_row[j].strip() if j < len(names_row) else ""
        names.append(re.sub(r"^Global (Angle|Translation) ", "", raw) or f"subject{len(names)}")
    if not groups:
        raise input_error(f"no RX,RY,RZ,TX,TY,TZ columns (section '{section}' holds no "
                          "rigid-body poses)", "export the Segments (Nexus) or Objects "
                          "(Tracker) section", str(path))
    name = _pick_body(names, opts.rigid_body, path, "subject")
    j = groups[names.index(name)]
    form, rot_scale = _parse_rotation(opts.rotation, units[j] if j < len(units) else "", path)
    pos_unit = (units[j + 3].strip().lower() if j + 3 < len(units) else "") or "mm"
    if pos_unit not in _LENGTH:
        raise input_error(f"unknown position unit '{pos_unit}' in the units row",
                          "re-export in mm", str(path))
    try:
        file_rate: float | None = float(head[1][0]) if head[1] and head[1][0].strip() else None
    except ValueError:
        file_rate = None
    rate = opts.mocap_rate or file_rate
    if rate is None or not rate > 0:
        raise input_error("no frame rate in the file (frame numbers only)",
                          "pass --mocap-rate HZ (the frame rate of the capture); the clock "
                          "offset to the IMU is then found by the clock search", str(path))
    if opts.mocap_rate and file_rate and abs(opts.mocap_rate - file_rate) > 1e-9:
        notes.append(f"{path}: --mocap-rate {opts.mocap_rate:g} Hz overrides the file's "
                     f"{file_rate:g} Hz")
    data = _numbers(path, 5, [0, *range(j, j + 6)])
    frames = data[0]
    R = _vicon_rotation(np.stack([data[c] for c in range(j, j + 3)], axis=1) * rot_scale,
                        form)
    q = np.full((len(R), 4), np.nan)
    ok = np.isfinite(R).all(axis=(1, 2))
    q[ok] = so3.rotmat_to_quat(R[ok])
    p = np.stack([data[c] for c in range(j + 3, j + 6)], axis=1) * _LENGTH[pos_unit]
    label = f"{path} [{name}]"
    notes.append(f"{label}: Vicon {fmt.split('-')[1].title()} export at {rate:g} Hz, {form} "
                 f"rotations, {pos_unit}; stamps are frame / rate (no absolute time)")
    return PoseTable(_stamps_from_frames(frames, rate), q, p,
                     Lines(label, path, skip=5, comment=None))


# --- the registry's records ------------------------------------------------------------------

def _poses(path: Path, opts: ReadOptions, notes: list[str]) -> PoseTable:
    return export_table(path, opts.export, notes)


def _format(key: str, name: str) -> Format:
    return Format(key, name, lambda p: p.is_file() and sniff_export(p) == key,
                  read_poses=_poses, options=frozenset({"rigid_body", "rotation", "mocap_rate"}))


MOTIVE = _format("motive", "Motive CSV export")
VICON_NEXUS = _format("vicon-nexus", "Vicon Nexus CSV export")
VICON_TRACKER = _format("vicon-tracker", "Vicon Tracker CSV export")
