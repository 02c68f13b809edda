"""Result files by kind: every file mocap-calib writes starts with ``kind`` and ``version``
(:mod:`mocap_calib.core.versioned`); files written before that are recognised once, here,
by the keys their kind always had.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mocap_calib.core.intrinsics.multipos.result import MultiposResult
from mocap_calib.core.intrinsics.noise_result import AllanResult
from mocap_calib.core.versioned import KindError
from mocap_calib.errors import InputError
from mocap_calib.io.yaml_io import INTRINSICS_NUMBERS, NOISE_KEYS, load_yaml, non_finite

#: How messages name each kind of file.
KIND_NAMES = {
    "calibration": "a 'mocap-calib calibrate' result",
    "intrinsics": "multipos intrinsics",
    "noise": "a noise file (Kalibr imu.yaml keys)",
}

INTRINSICS_FIX = "pass an intrinsics YAML written by 'mocap-calib multipos'"


def file_kind(data: dict[str, Any]) -> str | None:
    """The kind of a result file: its ``kind`` key, or for files written before ``kind``
    existed the kind their keys identify; None if neither."""
    kind = data.get("kind")
    if isinstance(kind, str):
        return kind
    if "T_marker_imu" in data:
        return "calibration"
    if any(k in data for k in NOISE_KEYS):
        return "noise"
    if "accel_matrix" in data and "gyro_matrix" in data:
        return "intrinsics"
    return None


def describe_kind(kind: str | None) -> str:
    """``a 'mocap-calib calibrate' result``, ... for messages."""
    if kind is None:
        return "not a mocap-calib result"
    return KIND_NAMES.get(kind, f"a mocap-calib '{kind}' file")


def read_intrinsics(path: Path | str) -> MultiposResult:
    """Read multipos intrinsics (values and sigmas of every parameter).

    Raises:
        InputError: the file is missing, is another kind of file (a calibrate result, a noise
            file), was written by a newer mocap-calib, or has missing or malformed entries (a
            simulator truth file has no sigmas).
    """
    data = load_yaml(path, "multipos intrinsics file")
    kind = file_kind(data)
    if kind != "intrinsics":
        raise InputError(f"{path}: is {describe_kind(kind)}, not multipos intrinsics; "
                         f"{INTRINSICS_FIX}")
    if not isinstance(data.get("sigma"), dict):
        raise InputError(f"{path}: no 'sigma: {{...}}' (a simulator truth file has no "
                         f"sigmas); {INTRINSICS_FIX}")
    bad = non_finite(data, INTRINSICS_NUMBERS)
    if bad:
        raise InputError(f"{path}: {bad}, not a finite number; {INTRINSICS_FIX}")
    try:
        return MultiposResult.from_dict(data)
    except KindError as err:
        raise InputError(f"{path}: {err}") from None
    except (TypeError, ValueError, KeyError, AttributeError) as err:
        raise InputError(f"{path}: {err}; {INTRINSICS_FIX}") from None


def read_noise_result(path: Path | str) -> AllanResult:
    """Read a noise file written by ``mocap-calib allan`` (with its curves).

    Raises:
        InputError: missing file, another kind, a newer version or malformed entries.
    """
    data = load_yaml(path, "noise file")
    kind = file_kind(data)
    fix = "pass a noise YAML written by 'mocap-calib allan'"
    if kind != "noise":
        raise InputError(f"{path}: is {describe_kind(kind)}, not a noise file; {fix}")
    try:
        return AllanResult.from_dict(data)
    except KindError as err:
        raise InputError(f"{path}: {err}") from None
    except (TypeError, ValueError, KeyError, AttributeError) as err:
        raise InputError(f"{path}: malformed noise file ({err}); {fix}") from None
