"""The input formats, in the order they are recognised: one record per format
(:class:`~mocap_calib.io.reading.Format`, defined in the format's module) and one line each in
:data:`FORMATS`. The loader asks :func:`sniff` which format a path holds and reads it with the
record's functions; nothing else names a format.

Recognition is by content, first match wins: ROS bags and MCAP files (containers), a folder
(EuRoC ``mav0``), a PX4 ULog, a Crazyflie uSD log (binary headers), Motive and Vicon exports
(their first line), EuRoC CSVs (their header), TUM trajectories (whitespace-separated, 8
columns, or more after a unit quaternion), and last any delimited table read with a column map.

Before that, a path that cannot be read as a file is refused for what it is: missing, a pipe
or device (``<(zcat ...)``), a compressed file; after it, a binary file no format recognised.
"""

from __future__ import annotations

import stat
from pathlib import Path

from mocap_calib.errors import input_error
from mocap_calib.io.formats import bags, euroc, generic, mocap_exports, tum, ulog
from mocap_calib.io.formats.crazyflie import usd
from mocap_calib.io.reading import Format

#: Every format, in the order of recognition (the last recognises anything).
FORMATS: list[Format] = [
    bags.ROSBAG2,
    bags.ROSBAG1,
    bags.MCAP,
    euroc.MAV0,
    ulog.FORMAT,
    usd.FORMAT,
    mocap_exports.MOTIVE,
    mocap_exports.VICON_NEXUS,
    mocap_exports.VICON_TRACKER,
    euroc.EUROC_IMU,
    euroc.EUROC_POSES,
    tum.FORMAT,
    generic.FORMAT,
]

#: Magic bytes of compressed files -> (their name, the command that decompresses them).
_COMPRESSED = {b"\x1f\x8b": ("gzip", "gunzip -k FILE"), b"BZh": ("bzip2", "bunzip2 -k FILE"),
               b"\xfd7zXZ\x00": ("xz", "unxz -k FILE"), b"\x28\xb5\x2f\xfd": ("zstd",
               "unzstd FILE"), b"PK\x03\x04": ("zip", "unzip FILE")}


def register(fmt: Format, before: str = "generic") -> None:
    """Add a format, recognised just before the format ``before`` (the catch-all by default)."""
    unregister(fmt.key)
    FORMATS.insert(next(i for i, f in enumerate(FORMATS) if f.key == before), fmt)


def unregister(key: str) -> None:
    FORMATS[:] = [f for f in FORMATS if f.key != key]


def find(key: str) -> Format:
    """The format of ``key`` (``--mocap-format`` and ``--mav0`` name theirs)."""
    for f in FORMATS:
        if f.key == key:
            return f
    raise input_error(f"unknown format '{key}'", "use one of: " +
                      ", ".join(f.key for f in FORMATS))


def check_readable(path: Path) -> None:
    """Refuse a path that is no file or folder to read, naming what it is."""
    try:
        mode = path.stat().st_mode
    except OSError:
        raise input_error("file not found", "check the path", str(path)) from None
    if stat.S_ISDIR(mode):
        return
    if not stat.S_ISREG(mode):
        what = "a pipe (such as <(zcat ...))" if stat.S_ISFIFO(mode) else "a device or socket"
        raise input_error(f"not a regular file but {what}, which can be read only once",
                          "write it to a file first (e.g. zcat log.csv.gz > log.csv) and pass "
                          "that file", str(path))
    with open(path, "rb") as f:
        head = f.read(8)
    for magic, (name, tool) in _COMPRESSED.items():
        if head.startswith(magic):
            raise input_error(f"the file is {name}-compressed", f"decompress it first ({tool}) "
                              "and pass the result", str(path))


def _binary(path: Path) -> bool:
    """A NUL byte in the first 4 kB: no text table."""
    if not path.is_file():
        return False
    with open(path, "rb") as f:
        return b"\0" in f.read(4096)


def sniff(path: Path | str, *, columns: bool = False) -> Format:
    """The format of ``path``: the first record that recognises it.

    Args:
        path: The file or folder.
        columns: A column map is given for the stream read from it (formats that yield to one,
            TUM, are then passed over).

    Raises:
        InputError: the path is missing, not a regular file, compressed, or binary without
            a format that recognises it.
    """
    path = Path(path)
    check_readable(path)
    for fmt in FORMATS:
        if columns and fmt.yields_to_columns:
            continue
        if fmt.sniff(path):
            if fmt is FORMATS[-1] and _binary(path):
                raise input_error("a binary file of no format this tool reads (" +
                                  ", ".join(f.name for f in FORMATS[:-1]) + ")",
                                  "pass the recording in one of those formats, or a text "
                                  "table with --columns", str(path))
            return fmt
    raise input_error("format not recognised", "pass a supported format", str(path))
