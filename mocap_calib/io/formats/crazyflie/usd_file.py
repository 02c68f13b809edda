"""The Crazyflie's event-based uSD-card log, decoded as the firmware writes it.

The layout (Bitcraze documents it with the firmware: ``tools/usdlog/cfusdlog.py``), all
numbers little-endian:

- byte 0: ``0xBC``; bytes 1-2: the format version (1 or 2); bytes 3-4: the number of event
  types;
- per event type: its id (uint16), its name (NUL-terminated), the number of its variables
  (uint16), and per variable ``name(t)`` (NUL-terminated) with ``t`` the variable's type as a
  Python ``struct`` character (``f`` float32, ``B`` uint8, ``h`` int16, ...);
- the events, back to back: the event id (uint16), the stamp (version 1: uint32 milliseconds;
  version 2: uint64 microseconds), then the variables packed without padding;
- the last 4 bytes: the CRC-32 of everything before them.

All stamps are on the drone's one clock. Every way a file can be damaged (cut short, a
damaged header, an event id the header does not define, a CRC that does not match) is refused
in one line naming the byte.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mocap_calib.errors import InputError, input_error

MAGIC = 0xBC
VERSIONS = (1, 2)
#: Event header bytes (id + stamp) and stamp type per version, and ns per stamp unit.
_STAMP = {1: ("<u4", 6, 1_000_000), 2: ("<u8", 10, 1_000)}
#: ``struct`` type characters of the variables -> numpy dtypes (little-endian).
_TYPES = {"b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "q": "<i8",
          "Q": "<u8", "e": "<f2", "f": "<f4", "d": "<f8"}
_FIX = ("copy the log from the uSD card again (the firmware closes a log, with its CRC, when "
        "logging stops cleanly)")
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class Event:
    """One event type of the log and its records.

    Attributes:
        name: The event's name (``estGyroscope``).
        fields: Its variables' names, in the file's order (``gyro.x``).
        stamps_ns: (N,) integer stamps in nanoseconds on the drone's clock.
        values: Field name -> (N,) float64 values as logged.
    """

    name: str
    fields: tuple[str, ...]
    stamps_ns: IntArray
    values: dict[str, NDArray[np.float64]]

    def __len__(self) -> int:
        return len(self.stamps_ns)

    def describe(self) -> str:
        return f"{self.name} ({', '.join(self.fields) or 'no fields'}; {len(self)})"


@dataclass(frozen=True)
class UsdLog:
    """A decoded uSD log: its version and its events by name (header order)."""

    path: Path
    version: int
    events: dict[str, Event]

    def present(self) -> list[Event]:
        """The events with at least one record."""
        return [e for e in self.events.values() if len(e)]

    def listing(self) -> str:
        """``name (fields; count)`` of every event with records, for messages."""
        return "; ".join(e.describe() for e in self.present()) or "none"


def is_usd_log(path: Path) -> bool:
    """True when the file's first byte is the uSD log's ``0xBC`` (never the first byte of a
    text file: it is no ASCII character and cannot start a UTF-8 one)."""
    try:
        with open(path, "rb") as f:
            return f.read(1) == bytes([MAGIC])
    except OSError:
        return False


def _damaged(path: Path, what: str) -> InputError:
    return input_error(what, _FIX, str(path))


class _Header:
    """Reads the header's fields one after the other, refusing a header cut short."""

    def __init__(self, data: bytes, path: Path) -> None:
        self.data, self.path, self.pos = data, path, 5

    def u16(self) -> int:
        if self.pos + 2 > len(self.data):
            raise _damaged(self.path, f"the event definitions are cut short at byte "
                           f"{len(self.data)} (the file ends inside its header)")
        (v,) = struct.unpack_from("<H", self.data, self.pos)
        self.pos += 2
        return int(v)

    def text(self, what: str) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise _damaged(self.path, f"the event definitions are cut short: {what} at byte "
                           f"{self.pos} has no end (the file ends inside its header)")
        raw = self.data[self.pos:end]
        try:
            s = raw.decode("ascii")
        except UnicodeDecodeError:
            s = ""
        if not s or not s.isprintable():
            raise _damaged(self.path, f"the header is damaged: {what} at byte {self.pos} is "
                           f"not a name ({raw[:16]!r})")
        self.pos = end + 1
        return s


def _definitions(data: bytes, path: Path, version: int, count: int
                 ) -> tuple[dict[int, tuple[str, tuple[str, ...], np.dtype]], int]:
    """Event id -> (name, fields, record dtype), and the byte where the events start."""
    head = _Header(data, path)
    defs: dict[int, tuple[str, tuple[str, ...], np.dtype]] = {}
    names: set[str] = set()
    stamp = _STAMP[version]
    for _ in range(count):
        at = head.pos
        eid = head.u16()
        name = head.text("an event name")
        fields: list[tuple[str, str]] = []
        for _ in range(head.u16()):
            var = head.text(f"a variable of event {name}")
            if len(var) < 4 or var[-3] != "(" or var[-1] != ")" or var[-2] not in _TYPES:
                raise _damaged(path, f"the header is damaged: variable '{var}' of event "
                               f"{name} (byte {head.pos - len(var) - 1}) is not 'name(t)' with "
                               f"a type t of {''.join(_TYPES)}")
            fields.append((var[:-3], _TYPES[var[-2]]))
        if eid in defs or name in names:
            raise _damaged(path, f"the header is damaged: event id {eid} ('{name}', byte {at}) "
                           "is defined twice")
        dtype = np.dtype([("id", "<u2"), ("stamp", stamp[0]),
                          *((f"v{i}", t) for i, (_, t) in enumerate(fields))])
        defs[eid] = (name, tuple(f for f, _ in fields), dtype)
        names.add(name)
    return defs, head.pos


def _walk(data: bytes, path: Path, start: int, sizes: dict[int, int]
          ) -> tuple[IntArray, IntArray]:
    """Byte offsets and ids of the events from ``start`` to the CRC."""
    end = len(data) - 4
    pos = start
    starts: list[int] = []
    ids: list[int] = []
    while pos < end:
        if pos + 2 > len(data):
            break
        eid = data[pos] | (data[pos + 1] << 8)
        size = sizes.get(eid)
        if size is None:
            defined = ", ".join(str(i) for i in sorted(sizes))
            raise _damaged(path, f"the log is damaged at byte {pos} of {len(data)}: event id "
                           f"{eid} is not defined in its header (ids {defined})")
        starts.append(pos)
        ids.append(eid)
        pos += size
    if pos != end:
        raise _damaged(path, f"the log ends inside an event (its last event, at byte "
                       f"{starts[-1] if starts else start}, needs {pos + 4 - len(data)} bytes "
                       f"more): it is truncated")
    return np.asarray(starts, dtype=np.int64), np.asarray(ids, dtype=np.int64)


def read_usd_log(path: Path | str) -> UsdLog:
    """Decode a Crazyflie uSD log (the layout of the module doc).

    Raises:
        InputError: a missing or empty file, not a uSD log, an unknown version, a damaged
            header, an event id the header does not define, a file cut short, a CRC that does
            not match; one line naming the byte, with the fix.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise input_error(f"cannot read the file ({err.strerror})", "check the path",
                          str(path)) from None
    if not data:
        raise input_error("the file is empty", "pass the log the Crazyflie wrote", str(path))
    if data[0] != MAGIC:
        raise input_error(f"not a Crazyflie uSD log (its first byte is 0x{data[0]:02X}, not "
                          "0xBC)", "pass the log file from the uSD card", str(path))
    if len(data) < 9:
        raise _damaged(path, f"the file holds {len(data)} bytes: it ends inside its header")
    version, count = struct.unpack_from("<HH", data, 1)
    if version not in VERSIONS:
        raise input_error(f"uSD log format version {version}; this reader knows versions 1 and "
                          "2", "decode the log with the tools/usdlog of the firmware that "
                          "wrote it, or check that the file is a uSD log", str(path))
    defs, start = _definitions(data, path, int(version), int(count))
    starts, ids = _walk(data, path, start, {k: d[2].itemsize for k, d in defs.items()})
    crc = zlib.crc32(memoryview(data)[:-4])
    (stored,) = struct.unpack_from("<I", data, len(data) - 4)
    if crc != stored:
        raise _damaged(path, f"its CRC-32 (0x{stored:08X}) does not match its contents "
                       f"(0x{crc:08X}): the file is damaged or cut short")
    buf = np.frombuffer(data, dtype=np.uint8)
    ns_per = _STAMP[version][2]
    events = {}
    for eid, (name, fields, dtype) in defs.items():
        at = starts[ids == eid]
        rec = buf[at[:, None] + np.arange(dtype.itemsize)].view(dtype).reshape(len(at))
        events[name] = Event(name, fields, rec["stamp"].astype(np.int64) * ns_per,
                             {f: rec[f"v{i}"].astype(np.float64)
                              for i, f in enumerate(fields)})
    return UsdLog(path, int(version), events)
