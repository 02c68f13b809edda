"""Versioned plain-data forms of results: every file the tool writes says what it is.

A result class has a ``KIND`` (``calibration``, ``intrinsics``, ``noise``, ``diagnosis``, ...) and
a ``VERSION``; its ``to_dict`` starts with ``kind`` and ``version`` and its ``from_dict`` calls
:func:`check_kind` first, so a file of another kind, or one written by a newer mocap-calib, is
refused with a message instead of being misread by the keys it happens to have.
"""

from __future__ import annotations

from typing import Any


class KindError(ValueError):
    """A plain-data result of the wrong kind or of a newer version than this code reads."""


def header(kind: str, version: int) -> dict[str, Any]:
    """The first two keys of every result file."""
    return {"kind": kind, "version": int(version)}


def check_kind(d: dict[str, Any], kind: str, version: int,
               legacy: tuple[str, ...] = ()) -> int:
    """Check ``d['kind']`` and ``d['version']``; return the version.

    Args:
        d: the plain data.
        kind: the kind expected.
        version: the newest version this code reads.
        legacy: keys whose presence identifies a file of this kind written before ``kind``
            existed (version 1 files); without ``kind`` and without them, the file is refused.

    Raises:
        KindError: another kind, a missing kind, or a newer version.
    """
    found = d.get("kind")
    if found is None:
        if legacy and all(k in d for k in legacy):
            found = kind
        else:
            raise KindError(f"not a mocap-calib {kind} file (no 'kind' key)")
    if found != kind:
        raise KindError(f"this is a mocap-calib {found} file, not a {kind} file")
    try:
        v = int(d.get("version", 1))
    except (TypeError, ValueError):
        raise KindError(f"'version' must be an integer, got {d.get('version')!r}") from None
    if v > version:
        raise KindError(f"written by a newer mocap-calib ({kind} version {v}; this one reads up "
                        f"to {version}); upgrade mocap-calib")
    return v
