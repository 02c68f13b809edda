"""PX4 ULog files below the streams: the completeness check, parsing with ``pyulog``, topic
instances (``name:N``) and the logger's own dropout records.

A topic PX4 publishes several instances of (one per IMU: ``sensor_gyro``, ``sensor_accel``) is
named ``TOPIC:N`` with ``N`` pyulog's ``multi_id``, the instance number PX4's ``listener`` and
Flight Review show; ``TOPIC`` alone names the topic's only instance.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mocap_calib.errors import input_error

ULOG_MAGIC = b"ULog\x01\x12\x35"


def is_ulog(path: Path | str) -> bool:
    path = Path(path)
    if not path.is_file():
        return path.suffix == ".ulg"
    with open(path, "rb") as f:
        return f.read(7) == ULOG_MAGIC or path.suffix == ".ulg"


#: Message types of the ULog format (its header's ``msg_type``).
_TYPES = frozenset(b"FIMPQARDLCSOB")


def check_complete(path: Path) -> int:
    """The length of the file's complete messages: the file's length, or the byte where bytes
    that are no ULog message begin (junk appended to a log: a message type the format does not
    have, or data of a topic never subscribed).

    Raises:
        InputError: not a ULog, or a file that ends inside a message (a truncated copy).
    """
    data = path.read_bytes()
    if len(data) < 16 or data[:7] != ULOG_MAGIC:
        raise input_error("not a PX4 ULog file (no ULog header)",
                          "pass the .ulg file the autopilot wrote", str(path))
    view = memoryview(data)
    pos, n = 16, len(data)
    unpack = struct.Struct("<HB").unpack_from
    subscribed: set[int] = set()
    while pos + 3 <= n:
        size, kind = unpack(view, pos)
        msg_id = struct.unpack_from("<H", view, pos + 3)[0] if pos + 5 <= n else -1
        if kind not in _TYPES or (kind == ord("D") and msg_id not in subscribed):
            return pos
        if kind == ord("A") and pos + 6 <= n:
            subscribed.add(struct.unpack_from("<H", view, pos + 4)[0])
        pos += 3 + size
    if pos != n:
        raise input_error(f"the file ends inside a message (byte {n} of a message that needs "
                          f"{pos}): it is truncated", "copy the complete log from the vehicle "
                          "again", str(path))
    return n


def open_ulog(path: Path, names: list[str], notes: list[str] | None = None) -> Any:
    """The parsed log, holding the topics ``names`` only (pyulog's ``ULog``); bytes after the
    last complete message are left out, with a note."""
    from pyulog import ULog
    from pyulog.core import ULogException

    if not path.is_file():
        raise input_error("file not found", "check the path", str(path))
    end = check_complete(path)
    size = path.stat().st_size
    source: Any = str(path)
    if end < size:
        source = io.BytesIO(path.read_bytes()[:end])
        if notes is not None:
            notes.append(f"{path}: {size - end} trailing bytes after the last complete message "
                         f"(byte {end}) are no ULog messages; read up to them")
    try:
        return ULog(source, message_name_filter_list=names)
    except (ULogException, ValueError, struct.error, IndexError, KeyError) as err:
        raise input_error(f"cannot parse the ULog ({' '.join(str(err).split())[:120]})",
                          "copy the complete log from the vehicle again", str(path)) from None


@dataclass(frozen=True)
class Instance:
    """One instance of a logged topic."""

    name: str
    multi_id: int
    data: dict[str, np.ndarray]
    single: bool = True  # the topic's only instance

    @property
    def spec(self) -> str:
        return self.name if self.single and self.multi_id == 0 else f"{self.name}:{self.multi_id}"

    @property
    def device_id(self) -> int | None:
        ids = self.data.get("device_id")
        return int(ids[0]) if ids is not None and len(ids) else None

    def describe(self) -> str:
        n = len(self.data["timestamp"])
        dev = f", device 0x{self.device_id:06X}" if self.device_id is not None else ""
        return f"{self.spec} ({n} samples{dev})"


def instances(ulog: Any, name: str) -> list[Instance]:
    """The instances of topic ``name`` in the log, by instance number."""
    found = [d for d in ulog.data_list if d.name == name]
    return sorted((Instance(d.name, int(d.multi_id), d.data, len(found) == 1) for d in found),
                  key=lambda i: i.multi_id)


def parse_spec(spec: str) -> tuple[str, int | None]:
    """``"sensor_gyro:1"`` -> ``("sensor_gyro", 1)``; ``"sensor_combined"`` -> (name, None).
    A suffix that is not a number stays part of the name (and is then an unknown topic)."""
    name, sep, inst = spec.partition(":")
    if sep and inst.isdigit():
        return name, int(inst)
    return spec, None


def pick_instance(found: list[Instance], name: str, wanted: int | None, option: str,
                  source: str) -> Instance:
    """Instance ``wanted`` of ``name``, or the only one; several and none chosen: one line
    listing them."""
    listed = ", ".join(i.describe() for i in found)
    if wanted is None:
        if len(found) > 1:
            raise input_error(f"{len(found)} instances of {name} in the log: {listed}",
                              f"choose one with {option} {name}:N, e.g. {option} "
                              f"{found[0].spec}", source)
        return found[0]
    for i in found:
        if i.multi_id == wanted:
            return i
    raise input_error(f"no instance {wanted} of {name} in the log (instances: {listed})",
                      f"pass {option} with one of those", source)


def logged_topics(ulog: Any) -> str:
    """``name:N (samples)`` of every topic instance read, for messages."""
    counts = sorted((d.name, int(d.multi_id), len(d.data["timestamp"])) for d in ulog.data_list)
    return ", ".join(f"{n}:{m} ({k})" if m else f"{n} ({k})" for n, m, k in counts) or "none"


def stamps_us(data: dict[str, np.ndarray]) -> tuple[np.ndarray, str]:
    """Integer microsecond stamps of a topic: ``timestamp_sample`` (when the sensor sampled)
    where logged, else ``timestamp`` (when the message was published), and which one."""
    field = "timestamp_sample" if "timestamp_sample" in data else "timestamp"
    return data[field].astype(np.int64), field


def vector(data: dict[str, np.ndarray], base: str, n: int, alt: tuple[str, ...] = ()
           ) -> np.ndarray | None:
    """(N, n) float64 array of fields ``base[0..n-1]`` (or the fields ``alt``), None if absent."""
    keys = [f"{base}[{i}]" for i in range(n)]
    if all(k in data for k in keys):
        return np.stack([data[k].astype(np.float64) for k in keys], axis=1)
    if alt and all(k in data for k in alt):
        return np.stack([data[k].astype(np.float64) for k in alt], axis=1)
    return None


def dropout_note(ulog: Any, origin_us: int, source: str) -> str | None:
    """One line on the logger's own dropout records (data it could not write: its buffer was
    full), times in s from ``origin_us`` (the IMU start); None if there are none."""
    drops = [(int(d.timestamp), int(d.duration)) for d in ulog.dropouts]
    if not drops:
        return None
    ms = np.array([d for _, d in drops], dtype=float)
    k = int(np.argmax(ms))
    at = (drops[k][0] - origin_us) * 1e-6
    return (f"{source}: the logger recorded {len(drops)} dropout{'s' if len(drops) > 1 else ''} "
            f"(messages it could not write): {ms.sum():.0f} ms in all, the longest {ms[k]:.0f} ms "
            f"at {at:.3f} s from the IMU start")
