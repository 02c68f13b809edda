"""What a file that no reader recognises probably is, for its one-line refusal.

A file that is not EuRoC, TUM or a known export needs ``--columns``; but most such files are
one of those layouts with a column lost (an export that dropped ``q_z``, a TUM file of 7
columns). The refusal then says so, naming the column when the header shows which one.
"""

from __future__ import annotations

from pathlib import Path

from mocap_calib.errors import InputError, input_error
from mocap_calib.io.formats.columns import IMU_KEYS, IMU_NAMES, POSE_KEYS, POSE_NAMES, name_key
from mocap_calib.io.formats.layout import WHITESPACE, Layout, sniff_layout

#: The generic fix's example column map.
COLUMNS_EXAMPLE = "--columns 't=0,gyro=1:4,accel=4:7,quat=7:11,pos=11:14' or --columns broad"
#: The example of the IMU-only commands.
IMU_ONLY_EXAMPLE = ("--columns 't=0,gyro=1:4,accel=4:7' (imu_tk's two files: --accel FILE "
                    "--gyro FILE)")
_LAYOUTS = {"imu": (IMU_KEYS, IMU_NAMES, "EuRoC IMU", "time, gyro x y z, accel x y z"),
            "mocap": (POSE_KEYS, POSE_NAMES, "EuRoC mocap", "time, position x y z, "
                      "quaternion w x y z")}


def _missing_euroc(names: tuple[str, ...] | None, stream: str) -> list[str] | None:
    """The EuRoC names a header lacks when its names are EuRoC's in order with some left out
    (at least the time and three more present), else None."""
    if names is None:
        return None
    keys, full, _, _ = _LAYOUTS[stream]
    got = [name_key(n) for n in names]
    if len(got) < 4 or got[0] != keys[0]:
        return None
    it = iter(enumerate(keys))
    present = set()
    for k in got:
        for i, key in it:
            if key == k:
                present.add(i)
                break
        else:
            return None  # a name that is not EuRoC's (or out of order)
    missing = [full[i] for i in range(len(keys)) if i not in present]
    return missing or None


def _short_by_one(layout: Layout, stream: str) -> str | None:
    """A headerless (or non-EuRoC) file one column short of EuRoC's or TUM's layout."""
    n = layout.n_fields
    if stream == "mocap" and n == 7:
        if layout.sep == WHITESPACE:
            return ("TUM rows have 8 columns (t x y z qx qy qz qw), this one has 7 (a "
                    "position or quaternion column missing?)")
        return ("EuRoC mocap rows have 8 columns (time, position x y z, quaternion w x y z), "
                "this one has 7 (a position or quaternion column missing?)")
    if stream == "imu" and n == 6:
        return ("EuRoC IMU rows have 7 columns (time, gyro x y z, accel x y z), this one has "
                "6 (a gyro or accel column missing?)")
    return None


def _first_stamp(layout: Layout) -> float | None:
    """The first data row's first number (the time column of EuRoC and TUM)."""
    with open(layout.path, encoding="utf-8", errors="replace") as f:
        for i, line in enumerate(f):
            if i == layout.skip:
                tokens = line.split() if layout.sep == WHITESPACE else line.split(layout.sep)
                try:
                    return float(tokens[0])
                except (ValueError, IndexError):
                    return None
    return None


def headerless_euroc_poses(path: Path | str) -> InputError | None:
    """A headerless file of 8 or more columns whose stamps are nanoseconds (any delimiter):
    EuRoC pose rows without EuRoC's header, which TUM's reading (seconds, ``xyzw``) would get
    wrong twice. None for anything else."""
    layout = sniff_layout(path)
    stamp = _first_stamp(layout) if layout.names is None and layout.n_fields >= 8 else None
    if stamp is None or stamp < 1e15:
        return None
    return input_error(f"{layout.n_fields} columns of nanosecond stamps without a header: "
                       "EuRoC pose rows "
                       "(time, position x y z, quaternion w x y z) without EuRoC's header line?",
                       "add the header of docs/conventions.md, or pass --columns "
                       "'t=0,pos=1:4,quat=4:8' --time-unit ns", str(path))


def unrecognised(path: Path | str, stream: str, example: str = COLUMNS_EXAMPLE
                 ) -> InputError:
    """The refusal of a file no reader recognises, given as the ``stream`` (``imu``,
    ``mocap`` or ``both``) input and without ``--columns``."""
    layout = sniff_layout(path)
    fix = f"say which columns hold what with --columns, e.g. {example}"
    if stream not in _LAYOUTS:
        return input_error("format not recognised (not EuRoC or TUM)", fix, str(path))
    keys, _, name, what = _LAYOUTS[stream]
    missing = _missing_euroc(layout.names, stream)
    if missing is not None:
        shown = ", ".join(m.split(" [")[0] for m in missing)
        return input_error(f"{name} rows have {len(keys)} columns ({what}), this one has "
                           f"{layout.n_fields} (missing {shown}?)",
                           "write every column of the EuRoC layout (docs/conventions.md), or "
                           "say which columns hold what with --columns", str(path))
    if stream == "mocap" and (euroc := headerless_euroc_poses(path)) is not None:
        return euroc
    short = _short_by_one(layout, stream)
    if short is not None:
        return input_error(short, "write the missing column, or say which columns hold what "
                           "with --columns", str(path))
    return input_error("format not recognised (not EuRoC or TUM)", fix, str(path))
