"""YAML files: calibration results, truth files, noise models, priors.

Results are versioned (``version``); loading a file written by a newer mocap-calib fails with a
clear message instead of misreading it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from mocap_calib.core.model.plausible import PlausibleLimits
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.model.versioned import KindError
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.errors import InputError
from mocap_calib.io.atomic import check_writable as check_writable  # re-exported
from mocap_calib.io.atomic import write_text


def _plain(x: Any) -> Any:
    """numpy scalars/arrays -> Python floats/lists so YAML stays plain."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x


class _Dumper(yaml.SafeDumper):
    """Lists of numbers inline (``[x, y, z]``), mappings in block style."""


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(isinstance(v, (int, float)) or v is None for v in data) or all(
        isinstance(v, list) and all(isinstance(x, (int, float)) or x is None for x in v)
        for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=bool(flow and data))


_Dumper.add_representer(list, _represent_list)


def save_yaml(path: str | Path, data: dict[str, Any], header: str | None = None) -> Path:
    """Write ``data`` as YAML (keys in insertion order), with an optional comment header."""
    text = yaml.dump(_plain(data), Dumper=_Dumper, sort_keys=False, allow_unicode=True, width=100)
    if header:
        text = "".join(f"# {line}\n" for line in header.splitlines()) + text
    return save_text(path, text)


def save_text(path: str | Path, text: str) -> Path:
    """Write a text file atomically, or raise a one-line :class:`InputError`."""
    return write_text(path, text)


def load_yaml(path: str | Path, what: str = "YAML file") -> dict[str, Any]:
    """Read a YAML mapping, or raise a one-line :class:`InputError`."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} not found; check the path")
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise InputError(f"{path}: cannot read the {what} ({err.strerror or err}); check the "
                         "file's permissions") from None
    if not raw.strip():
        raise InputError(f"{path}: the {what} is empty; pass the YAML file meant here")
    try:
        if b"\0" in raw[:65536]:
            raise UnicodeDecodeError("utf-8", raw, 0, 1, "NUL byte")
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{path}: a binary file, not a YAML {what}; pass the YAML file meant "
                         "here") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise InputError(f"{path}{where}: not valid YAML ({getattr(err, 'problem', err)}); "
                         "fix the syntax") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a YAML mapping of keys to values; check the file")
    return data


def save_result(path: str | Path, result: CalibrationResult) -> Path:
    """Write a calibration result (``docs/conventions.md`` keys first)."""
    header = ("mocap-calib calibration result (SI units; 1-sigma under 'sigma').\n"
              "T_marker_imu is T_MI: x_M = R_MI x_I + p_MI. See docs/conventions.md.")
    return save_yaml(path, result.to_dict(), header)


def load_result(path: str | Path) -> CalibrationResult:
    """Read a result written by :func:`save_result` (or a truth file of the simulator)."""
    data = load_yaml(path, "calibration result")
    try:
        return CalibrationResult.from_dict(data)
    except KindError as err:
        raise InputError(f"{path}: {err}; give a result written by 'mocap-calib calibrate'"
                         ) from None
    except KeyError as err:
        raise InputError(f"{path}: {err.args[0]}") from None
    except (TypeError, ValueError, AttributeError) as err:
        raise InputError(f"{path}: malformed result ({err}); regenerate it with mocap-calib "
                         "calibrate") from None


NOISE_KEYS = ("gyroscope_noise_density", "gyroscope_random_walk",
              "accelerometer_noise_density", "accelerometer_random_walk")


def load_noise(path: str | Path, base: NoiseModel | None = None) -> NoiseModel:
    """Noise densities from a Kalibr ``imu.yaml``, an EuRoC ``sensor.yaml`` or ``allan`` output.

    Missing keys keep the values of ``base`` (default: EuRoC ADIS16448).
    """
    data = load_yaml(path, "noise file")
    base = base or NoiseModel()
    values = base.to_dict()
    found = 0
    for key in (*NOISE_KEYS, "mocap_position_sigma", "mocap_rotation_sigma"):
        if key in data and data[key] is not None:
            try:
                v = float(data[key])
            except (TypeError, ValueError):
                raise InputError(f"{path}: '{key}' must be a number, got {data[key]!r}") from None
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{path}: '{key}' must be a positive number, got {v}")
            values[key] = v
            found += key in NOISE_KEYS
    if found == 0:
        raise InputError(f"{path}: no noise keys found (expected Kalibr imu.yaml keys such as "
                         "gyroscope_noise_density); pass a noise file written by 'mocap-calib "
                         "allan' or Kalibr")
    return NoiseModel.from_dict(values)


def load_plausible(path: str | Path) -> PlausibleLimits:
    """Plausibility limits: the defaults (``docs/diagnosis.md``) overridden by a YAML mapping,
    e.g. ``accel_bias: 2.0`` or ``effects: {gyro_g_sensitivity: {max: 5e-3}}``."""
    data = load_yaml(path, "plausibility limits file")
    try:
        return PlausibleLimits.from_dict(data)
    except KeyError as err:
        raise InputError(f"{path}: unknown limit '{err.args[0]}'; see docs/diagnosis.md for the "
                         "names") from None
    except (TypeError, ValueError, AttributeError) as err:
        raise InputError(f"{path}: limits must be numbers ({err}); see docs/diagnosis.md"
                         ) from None
