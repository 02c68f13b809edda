"""Columns: the maps of generic CSVs (which columns hold time, gyro, accel, quaternion,
position), header names, and the fixed columns of EuRoC's layouts.

The ``--columns`` grammar is in :mod:`mocap_calib.io.formats.generic`; :func:`parse_columns`
reads it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from mocap_calib.errors import InputError, input_error

Col = int | str

IMU_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
POSE_HEADER = ("#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], "
               "q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z []")


def name_key(name: str) -> str:
    """Header name without ``#``, bracketed unit and case: ``'#timestamp [ns]' -> 'timestamp'``."""
    n = name.strip().lstrip("#").strip()
    return re.sub(r"\s*\[[^\]]*\]$", "", n).strip().lower()


IMU_NAMES = tuple(n.strip().lstrip("#") for n in IMU_HEADER.split(","))
POSE_NAMES = tuple(n.strip().lstrip("#") for n in POSE_HEADER.split(","))
IMU_KEYS = tuple(name_key(n) for n in IMU_NAMES)
POSE_KEYS = tuple(name_key(n) for n in POSE_NAMES)


@dataclass(frozen=True)
class ColumnMap:
    """Which columns of a generic CSV hold which quantity (0-based indices or header names).

    Attributes:
        time: The time column.
        gyro: Gyro x, y, z, or None.
        accel: Accel x, y, z, or None.
        quat: Quaternion, 4 columns in the file's order (see ``quat_order``), or None.
        position: Position x, y, z, or None.
    """

    time: Col = 0
    gyro: tuple[Col, ...] | None = None
    accel: tuple[Col, ...] | None = None
    quat: tuple[Col, ...] | None = None
    position: tuple[Col, ...] | None = None

    @property
    def has_imu(self) -> bool:
        return self.gyro is not None and self.accel is not None

    @property
    def has_mocap(self) -> bool:
        return self.quat is not None and self.position is not None

    def check(self) -> ColumnMap:
        """Raise if a group has the wrong number of columns or a stream is half given."""
        _check_counts({"gyro": self.gyro, "accel": self.accel, "quat": self.quat,
                       "position": self.position})
        if (self.gyro is None) != (self.accel is None):
            raise input_error("the IMU stream needs both gyro= and accel=", COLUMNS_FIX,
                              "--columns")
        if (self.quat is None) != (self.position is None):
            raise input_error("the mocap stream needs both quat= and pos=", COLUMNS_FIX,
                              "--columns")
        return self


COLUMNS_FIX = ("write --columns like 't=0,gyro=1:4,accel=4:7,quat=7:11,pos=11:14' "
                "(0-based, A:B is a range, names separated by |)")

#: BROAD (``../shared/data/broad_*/data.csv``): seconds, rad/s, m/s^2, wxyz, metres.
BROAD = ColumnMap(
    time="t [s]",
    gyro=("gyr_x [rad/s]", "gyr_y [rad/s]", "gyr_z [rad/s]"),
    accel=("acc_x [m/s^2]", "acc_y [m/s^2]", "acc_z [m/s^2]"),
    quat=("opt_qw", "opt_qx", "opt_qy", "opt_qz"),
    position=("opt_px [m]", "opt_py [m]", "opt_pz [m]"),
)

PRESETS: dict[str, ColumnMap] = {"broad": BROAD}

_KEYS = {"t": "time", "time": "time", "gyro": "gyro", "gyr": "gyro", "w": "gyro",
         "accel": "accel", "acc": "accel", "a": "accel", "quat": "quat", "q": "quat",
         "pos": "position", "position": "position", "p": "position"}


def parse_columns(spec: str, flag: str = "--columns") -> ColumnMap:
    """Build a :class:`ColumnMap` from a ``--columns`` string (grammar in the module doc).

    Args:
        spec: E.g. ``"t=0,gyro=1:4,accel=4:7"`` or ``"broad"``.
        flag: The option it was given with (``--imu-columns``...), for messages.

    Returns:
        The column map.

    Raises:
        InputError: on a malformed string.
    """
    try:
        return _parse(spec)
    except InputError as err:
        if flag == "--columns":
            raise
        raise InputError(str(err).replace("--columns", flag)) from None


def _parse(spec: str) -> ColumnMap:
    text = spec.strip()
    if text.lower() in PRESETS:
        return PRESETS[text.lower()]
    found: dict[str, tuple[Col, ...]] = {}
    for item in (i.strip() for i in text.split(",")):
        if not item:
            continue
        key, eq, value = item.partition("=")
        field = _KEYS.get(key.strip().lower())
        if not eq or field is None:
            raise input_error(f"cannot read {item!r} (keys: t, gyro, accel, quat, pos)",
                              COLUMNS_FIX, "--columns")
        if field in found:
            raise input_error(f"{key.strip()}= is given twice", COLUMNS_FIX, "--columns")
        found[field] = _parse_cols(value.strip())
    _check_counts({k: v for k, v in found.items() if k != "time"})
    if "time" not in found:
        raise input_error("no time column (t=)", COLUMNS_FIX, "--columns")
    if len(found["time"]) != 1:
        raise input_error(f"t= names {len(found['time'])} columns, not 1", COLUMNS_FIX,
                          "--columns")
    return ColumnMap(time=found["time"][0], gyro=found.get("gyro"), accel=found.get("accel"),
                     quat=found.get("quat"), position=found.get("position")).check()


#: Columns of each group, and what they hold (for messages).
_COUNTS = {"gyro": (3, "the gyro's x, y, z"), "accel": (3, "the accelerometer's x, y, z"),
           "quat": (4, "a quaternion's w, x, y, z"), "position": (3, "the position's x, y, z")}


def _check_counts(groups: dict[str, tuple[Col, ...] | None]) -> None:
    for field, cols in groups.items():
        n, what = _COUNTS[field]
        if cols is not None and len(cols) != n:
            key = "pos" if field == "position" else field
            raise input_error(f"{key}= names {len(cols)} columns, but {what} are {n}",
                              COLUMNS_FIX, "--columns")


def _parse_cols(value: str) -> tuple[Col, ...]:
    m = re.fullmatch(r"(\d+)\s*:\s*(\d+)", value)
    if m:
        cols: tuple[Col, ...] = tuple(range(int(m.group(1)), int(m.group(2))))
    else:
        cols = tuple(int(v) if re.fullmatch(r"\d+", v) else v
                     for v in (p.strip() for p in value.split("|")))
    if not cols or any(c == "" for c in cols):
        raise input_error(f"empty column in {value!r}", COLUMNS_FIX, "--columns")
    return cols
