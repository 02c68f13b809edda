"""What the batch keeps on disk: content hashes of a session's inputs, and the ``session.batch``
record inside each result that lets a rerun skip it (files are written by io/atomic.py)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import mocap_calib
from mocap_calib.batch.manifest import SessionEntry
from mocap_calib.batch.session import REFUSED
from mocap_calib.errors import InputError
from mocap_calib.io.yaml_io import load_yaml
from mocap_calib.workflows.requests import to_flat

#: Files of a mav0 folder that can change a calibration (not the camera images).
_FOLDER_SUFFIXES = (".csv", ".yaml", ".yml", ".txt")
_CHUNK = 1 << 20


class Digests:
    """SHA-256 of file contents, each file read once per batch (a swarm's shared mocap take)."""

    def __init__(self) -> None:
        self._cache: dict[Path, str] = {}

    def file(self, path: Path) -> str:
        path = path.resolve()
        if path not in self._cache:
            h = hashlib.sha256()
            try:
                with path.open("rb") as f:
                    while chunk := f.read(_CHUNK):
                        h.update(chunk)
            except OSError as err:
                raise InputError(f"{path}: cannot read ({err.strerror or err}); check its "
                                 "permissions") from None
            self._cache[path] = h.hexdigest()
        return self._cache[path]

    def path(self, path: Path) -> str:
        if not path.is_dir():
            return self.file(path)
        parts = [f"{p.relative_to(path).as_posix()}={self.file(p)}"
                 for p in sorted(path.rglob("*")) if p.is_file() and p.suffix in _FOLDER_SUFFIXES]
        return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def input_hash(entry: SessionEntry, digests: Digests, history: list[str] | None = None) -> str:
    """Hash of everything that determines a session's result: the contents of its input files
    (not their names, so a moved data folder is still finished), its options, the hashes of
    the earlier sessions it takes priors from, and the mocap-calib version."""
    opts: dict[str, Any] = {}
    for key, value in to_flat(entry.request).items():
        if key in REFUSED:  # the outputs: not the session's (the batch writes its own)
            continue
        if isinstance(value, Path):
            value = digests.path(value)
        elif isinstance(value, tuple):
            value = [digests.path(v) if isinstance(v, Path) else v for v in value]
        elif value is not None and not isinstance(value, (bool, int, float, str)):
            value = str(value)  # e.g. the model
        opts[key] = value
    record = {"options": opts, "history": list(history or []),
              "imu_id": entry.imu_id, "date": entry.date, "version": mocap_calib.__version__}
    return hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()


def _batch_record(result_path: Path, key: str) -> str | None:
    if not result_path.is_file():
        return None
    try:
        data = load_yaml(result_path, "calibration result")
        return str(data["session"]["batch"][key])
    except (InputError, KeyError, TypeError):
        return None


def finished_hash(result_path: Path) -> str | None:
    """The ``session.batch.input_hash`` of an existing result, or None (absent, unreadable)."""
    return _batch_record(result_path, "input_hash")


def batch_id(result_path: Path) -> str | None:
    """The ``session.batch.id`` of an existing result: the session a batch wrote it for."""
    return _batch_record(result_path, "id")
