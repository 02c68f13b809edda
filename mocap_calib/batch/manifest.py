"""The batch manifest: a YAML list of sessions, checked completely before any work starts.

    defaults:            # optional: keys every session gets unless it sets them itself
      columns: broad
    sessions:
      - id: drone1-0301
        imu_id: drone1
        date: 2024-03-01
        imu: drone1/imu.csv
        mocap: take_0301.csv
        rigid_body: drone1
        model: base+time_offset

Besides ``id`` (a folder name under OUT), ``imu_id`` (the IMU or airframe) and ``date``, a
session takes any option of ``mocap-calib calibrate`` by its long name with underscores (the
folder argument is ``mav0``). Several takes of one rig make one calibration (one result with a
``takes:`` block, as ``calibrate --imu A --mocap A --imu B --mocap B``): ``imu: [a, b]`` with
``mocap: [a, b]`` in the same order, or ``mav0: [a, b]``. Relative paths are relative to the
manifest's folder. Every problem (missing file, unknown key, duplicate id, wrong type) is one
line.
"""

from __future__ import annotations

import datetime as dt
import difflib
import re
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mocap_calib.batch.session import REFUSED
from mocap_calib.errors import InputError
from mocap_calib.io.yaml_io import load_yaml
from mocap_calib.workflows.calibrate import CalibrateRequest
from mocap_calib.workflows.requests import from_flat, leaves

SESSION_KEYS = ("id", "imu_id", "date")
#: The manifest's option keys: every option of ``calibrate`` but its outputs.
_LEAVES = {leaf.name: leaf for leaf in leaves(CalibrateRequest) if leaf.name not in REFUSED}
ARG_KEYS = tuple(_LEAVES)
#: Keys whose values are folders, not files.
_FOLDERS = ("mav0",)
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
#: Names in OUT that the batch's own files take (OUT/batch.yaml, OUT/fleet/).
RESERVED_IDS = ("batch.yaml", "fleet")


class ManifestError(InputError):
    """Every problem of a manifest, one line each."""

    def __init__(self, problems: list[str]) -> None:
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


@dataclass(frozen=True)
class SessionEntry:
    """One checked session: where it goes, whose it is, when, and its ``calibrate`` request."""

    id: str
    imu_id: str
    date: str  # ISO form of the manifest's date
    time_ns: int  # the date as ns since the Unix epoch (UTC): the session's place in a trend
    request: CalibrateRequest


@dataclass(frozen=True)
class Manifest:
    path: Path
    sessions: list[SessionEntry]


def _kind(name: str) -> str:
    leaf = _LEAVES[name]
    if leaf.info.parse is not None:
        return "str"
    t = leaf.type
    if leaf.repeatable:
        return "paths"
    args = [a for a in typing.get_args(t) if a is not type(None)] or [t]
    for k, cls in (("path", Path), ("bool", bool), ("int", int), ("float", float),
                   ("str", str)):
        if args[0] is cls:
            return k
    raise AssertionError(name)


def _date_ns(value: Any) -> tuple[str, int] | None:
    if isinstance(value, str):
        text = value.strip()
        try:
            value = (dt.date.fromisoformat(text) if len(text) == 10
                     else dt.datetime.fromisoformat(text))
        except ValueError:
            return None
    if isinstance(value, dt.datetime):
        stamp = value if value.tzinfo else value.replace(tzinfo=dt.UTC)
        return value.isoformat(), int(round(stamp.timestamp() * 1e9))
    if isinstance(value, dt.date):
        midnight = dt.datetime(value.year, value.month, value.day, tzinfo=dt.UTC)
        return value.isoformat(), int(midnight.timestamp()) * 1_000_000_000
    return None


class _Checker:
    """Collects the problems of one manifest while building its sessions."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.root = path.parent
        self.problems: list[str] = []

    def bad(self, where: str, what: str, fix: str) -> None:
        self.problems.append(f"{self.path}: {where}: {what}; {fix}")

    def value(self, where: str, key: str, value: Any) -> Any:
        """The option's value in its type (paths resolved and checked), or None if wrong."""
        kind = _kind(key)
        if kind in ("path", "paths"):
            items = value if kind == "paths" and isinstance(value, list) else [value]
            out = []
            for v in items:
                if not isinstance(v, str) or not v.strip():
                    self.bad(where, f"{key} must be a path, got {v!r}", "give a file path")
                    return None
                p = Path(v).expanduser()
                p = p if p.is_absolute() else self.root / p
                if key in _FOLDERS and not p.is_dir():
                    self.bad(where, f"mav0 folder {p} not found", "check the path")
                elif key not in _FOLDERS and not p.exists():
                    self.bad(where, f"{key} file {p} not found",
                             "check the path (relative paths start at the manifest's folder)")
                out.append(p)
            return tuple(out) if kind == "paths" else out[0]
        if kind == "bool":
            if not isinstance(value, bool):
                self.bad(where, f"{key} must be true or false, got {value!r}", f"write {key}: true")
                return None
            return value
        if kind == "float":
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                self.bad(where, f"{key} must be a number, got {value!r}", "give a number")
                return None
            return float(value)
        if kind == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                self.bad(where, f"{key} must be a whole number, got {value!r}", "give e.g. 30")
                return None
            return value
        if isinstance(value, bool) or not isinstance(value, (str, int, float)):
            self.bad(where, f"{key} must be text, got {value!r}", "give a string")
            return None
        return str(value)

    def unknown(self, where: str, key: str) -> None:
        if key in REFUSED:
            self.bad(where, f"key '{key}' is not a batch option", REFUSED[key])
            return
        close = difflib.get_close_matches(key, [*SESSION_KEYS, *ARG_KEYS], n=1)
        hint = f"did you mean '{close[0]}'?" if close else \
            "use id, imu_id, date or a calibrate option with underscores, e.g. rigid_body"
        self.bad(where, f"unknown key '{key}'", hint)

    def options(self, where: str, raw: dict[str, Any]) -> dict[str, Any]:
        out = {}
        for key, v in raw.items():
            key = str(key)
            if key in SESSION_KEYS:
                continue
            if key not in ARG_KEYS:
                self.unknown(where, key)
            elif v is None:
                out[key] = None  # unsets a default
            else:
                checked = self.value(where, key, v)
                if checked is not None:
                    out[key] = checked
        return out


def _session(chk: _Checker, n: int, raw: Any, defaults: dict[str, Any],
             seen: dict[str, tuple[int, str]]) -> SessionEntry | None:
    where = f"session #{n}"
    if not isinstance(raw, dict):
        chk.bad(where, "is not a mapping", "write each session as 'key: value' lines under '- '")
        return None
    sid = raw.get("id")
    if isinstance(sid, (str, int)) and not isinstance(sid, bool) and _ID.match(str(sid)):
        sid = str(sid)
        where = f"session '{sid}' (#{n})"
        key = sid.casefold()  # one folder on the file systems of macOS and Windows
        if key in seen:
            first, other = seen[key]
            case = "" if other == sid else f" '{other}': ids that differ in case only name one " \
                "folder on macOS and Windows"
            chk.bad(where, f"duplicate id (also session #{first}{case})",
                    "give every session its own id")
        seen.setdefault(key, (n, sid))
        if key in RESERVED_IDS:
            chk.bad(where, f"the id '{sid}' names the batch's own OUT/{sid}",
                    "give the session another id")
    else:
        chk.bad(where, "missing or invalid id" if sid is None else f"invalid id {sid!r}",
                "give an id of letters, digits, '.', '_' or '-' (it names OUT/<id>/)")
        sid = None
    imu_id = raw.get("imu_id")
    if not isinstance(imu_id, (str, int)) or isinstance(imu_id, bool) or not str(imu_id):
        chk.bad(where, "missing imu_id", "name the IMU or airframe, e.g. imu_id: drone1")
    date = _date_ns(raw.get("date"))
    if date is None:
        chk.bad(where, "missing or unreadable date" if raw.get("date") is None else
                f"unreadable date {raw.get('date')!r}", "write it as 2024-03-01 or "
                "2024-03-01T14:30:00")
    opts = {k: v for k, v in {**defaults, **chk.options(where, raw)}.items() if v is not None}
    if opts.get("mav0") is None and (opts.get("imu") is None or opts.get("mocap") is None):
        chk.bad(where, "no inputs", "give mav0 (a folder) or both imu and mocap")
    elif opts.get("mav0") is not None and (opts.get("imu") or opts.get("mocap")):
        chk.bad(where, "both mav0 and imu/mocap", "give either a mav0 folder or imu and mocap")
    elif opts.get("mav0") is None and len(opts["imu"]) != len(opts["mocap"]):
        chk.bad(where, f"{len(opts['imu'])} imu and {len(opts['mocap'])} mocap files",
                "several takes are given as lists of pairs, in order: imu: [a, b] with mocap: "
                "[a, b] (the same file twice when one file holds both streams)")
    try:
        request = from_flat(CalibrateRequest, opts)
    except InputError as err:  # a value out of range, an unknown effect: one line
        chk.bad(where, str(err).split(";")[0], "fix that key")
        request = None
    if sid is None or date is None or not isinstance(imu_id, (str, int)) or request is None:
        return None
    return SessionEntry(sid, str(imu_id), date[0], date[1], request)


def load_manifest(path: str | Path) -> Manifest:
    """Read and check a manifest; raises :class:`ManifestError` listing every problem."""
    path = Path(path)
    data = load_yaml(path, "manifest")
    chk = _Checker(path)
    for key in data:
        if key not in ("sessions", "defaults"):
            chk.bad("top level", f"unknown key '{key}'", "the manifest has 'sessions' (a list) "
                    "and optionally 'defaults'")
    defaults_raw = data.get("defaults") or {}
    if not isinstance(defaults_raw, dict):
        chk.bad("defaults", "is not a mapping", "write 'key: value' lines under defaults")
        defaults_raw = {}
    for key in SESSION_KEYS:
        if key in defaults_raw and key != "date":
            chk.bad("defaults", f"'{key}' cannot be a default", "set it in each session")
    defaults = chk.options("defaults", {k: v for k, v in defaults_raw.items() if k != "id"})
    raw_sessions = data.get("sessions")
    if not isinstance(raw_sessions, list) or not raw_sessions:
        chk.bad("top level", "no sessions", "list them under 'sessions:'")
        raw_sessions = []
    seen: dict[str, tuple[int, str]] = {}
    sessions = []
    for n, raw in enumerate(raw_sessions, start=1):
        if isinstance(raw, dict) and "date" not in raw and "date" in defaults_raw:
            raw = {**raw, "date": defaults_raw["date"]}
        entry = _session(chk, n, raw, defaults, seen)
        if entry is not None:
            sessions.append(entry)
    if chk.problems:
        raise ManifestError(chk.problems)
    return Manifest(path, sessions)
