"""YAML files: calibration results, truth files, noise models, priors, manifests.

Results are versioned (``version``); loading a file written by a newer mocap-calib fails with a
clear message instead of misreading it.

Every YAML file is read by :func:`load_yaml`, which refuses in one line (file, line, key) what
would crash or mislead a plain ``yaml.safe_load``: files over :data:`MAX_YAML_BYTES`, nesting
deeper than :data:`MAX_DEPTH`, aliases that expand to more than :data:`MAX_ALIAS_VALUES`
values (a "billion laughs" file), integers of more than :data:`MAX_INT_DIGITS` digits, dates
that do not exist (``2024-02-30``) and a key given twice in one mapping (YAML keeps the last
silently). Numbers written with an exponent and no dot (``2e-4``, a string in YAML 1.1) are
numbers, in reading and writing alike.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.plausible import PlausibleLimits
from mocap_calib.core.result.calibration import CalibrationResult
from mocap_calib.core.versioned import KindError
from mocap_calib.errors import ConvergenceError, InputError
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


#: Limits of a YAML input (results are tens of kB, manifests of thousands of sessions a few MB).
MAX_YAML_BYTES = 16 << 20
MAX_DEPTH = 64
MAX_ALIAS_VALUES = 100_000
MAX_INT_DIGITS = 100

_INT = "tag:yaml.org,2002:int"
_FLOAT = "tag:yaml.org,2002:float"
_TIMESTAMP = "tag:yaml.org,2002:timestamp"
#: ``2e-4``, ``-1E+3``, ``1_000e3``: numbers with an exponent but no dot (YAML 1.2 floats).
_EXPONENT_FLOAT = re.compile(r"^[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+$")


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader that also reads ``2e-4`` as a number."""


class _Dumper(yaml.SafeDumper):
    """Lists of numbers inline (``[x, y, z]``), mappings in block style; a string that the
    loader would read as a number (``"2e-4"``) is quoted."""


for _cls in (_Loader, _Dumper):
    _cls.add_implicit_resolver(_FLOAT, _EXPONENT_FLOAT, list("-+0123456789"))


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


class _Refused(Exception):
    """A YAML document refused while its nodes are checked: the node and the problem."""

    def __init__(self, node: Node, where: str, problem: str) -> None:
        super().__init__(problem)
        self.node, self.where, self.problem = node, where, problem


def _key(node: Node) -> str:
    return str(node.value) if isinstance(node, ScalarNode) else "?"


def _check_scalar(loader: _Loader, node: ScalarNode, where: str) -> None:
    if node.tag == _INT:
        digits = sum(c.isalnum() for c in node.value)
        if digits > MAX_INT_DIGITS:
            raise _Refused(node, where, f"an integer of {digits} digits (at most "
                           f"{MAX_INT_DIGITS}); write the number meant")
    elif node.tag == _TIMESTAMP:
        try:
            loader.construct_yaml_timestamp(node)
        except (ValueError, OverflowError) as err:
            raise _Refused(node, where, f"the date {node.value} does not exist ({err}); write "
                           "a real date") from None


def _children(node: Node, where: str) -> list[tuple[Node, str]]:
    """The nodes under ``node`` with where they are (``sessions[2].date``); a key given twice
    in one mapping is refused."""
    if isinstance(node, SequenceNode):
        return [(v, f"{where}[{i}]") for i, v in enumerate(node.value)]
    if not isinstance(node, MappingNode):
        return []
    seen: set[str] = set()
    out: list[tuple[Node, str]] = []
    for k, v in node.value:
        name = _key(k)
        if isinstance(k, ScalarNode) and k.tag != "tag:yaml.org,2002:merge":
            if name in seen:
                raise _Refused(k, where, f"the key '{name}' is given twice in "
                               "one mapping (YAML keeps the last one silently); keep one")
            seen.add(name)
        sub = f"{where}.{name}" if where else name
        out += [(k, sub), (v, sub)]
    return out


def _check_nodes(loader: _Loader, root: Node) -> None:
    """Every scalar checked once (:func:`_check_scalar`), the nesting depth and the values
    that aliases add (a node reached again through an alias adds its whole subtree)."""
    size: dict[int, int] = {}
    stack: list[tuple[Node, str, int, bool]] = [(root, "", 0, False)]
    composed = 0
    while stack:
        node, where, depth, done = stack.pop()
        if done:
            size[id(node)] = 1 + sum(size[id(c)] for c, _ in _children(node, where))
            continue
        if id(node) in size:
            continue
        if depth > MAX_DEPTH:
            raise _Refused(node, where, f"nested more than {MAX_DEPTH} levels deep; "
                           "flatten the file")
        composed += 1
        if isinstance(node, ScalarNode):
            _check_scalar(loader, node, where)
            size[id(node)] = 1
            continue
        size[id(node)] = 0  # in progress: an alias back to it adds nothing more
        stack.append((node, where, depth, True))
        stack += [(c, w, depth + 1, False) for c, w in reversed(_children(node, where))
                  if id(c) not in size]
    if size[id(root)] - composed > MAX_ALIAS_VALUES:
        raise _Refused(root, "", f"its aliases (*name) expand to {size[id(root)]:,} values, "
                       f"more than {MAX_ALIAS_VALUES:,} beyond the file's own; write the values "
                       "out instead of nesting aliases")


def _parse(text: str) -> Any:
    """The document of ``text``, checked (:func:`_check_nodes`) before it is constructed."""
    loader = _Loader(text)
    try:
        root = loader.get_single_node()
        if root is None:
            return None
        _check_nodes(loader, root)
        return loader.construct_document(root)
    finally:
        loader.dispose()


def _read_text(path: Path, what: str) -> str:
    if not path.is_file():
        raise InputError(f"{path}: {what} not found; check the path")
    try:
        size = path.stat().st_size
        if size > MAX_YAML_BYTES:
            raise InputError(f"{path}: {size / 2**20:.0f} MB, more than a {what} can be "
                             f"({MAX_YAML_BYTES >> 20} MB); pass the YAML file meant here")
        with path.open("rb") as f:
            raw = f.read(MAX_YAML_BYTES + 1)
    except OSError as err:
        raise InputError(f"{path}: cannot read the {what} ({err.strerror or err}); check the "
                         "file's permissions") from None
    if len(raw) > MAX_YAML_BYTES:
        raise InputError(f"{path}: more than a {what} can be ({MAX_YAML_BYTES >> 20} MB); pass "
                         "the YAML file meant here")
    if not raw.strip():
        raise InputError(f"{path}: the {what} is empty; pass the YAML file meant here")
    try:
        if b"\0" in raw[:65536]:
            raise UnicodeDecodeError("utf-8", raw, 0, 1, "NUL byte")
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{path}: a binary file, not a YAML {what}; pass the YAML file meant "
                         "here") from None
    return text


def load_yaml(path: str | Path, what: str = "YAML file") -> dict[str, Any]:
    """Read a YAML mapping, or raise a one-line :class:`InputError` (see the module doc)."""
    path = Path(path)
    text = _read_text(path, what)
    try:
        data = _parse(text)
    except _Refused as err:
        at = f", at '{err.where}'" if err.where else ""
        raise InputError(f"{path}, line {err.node.start_mark.line + 1}{at}: {err.problem}"
                         ) from None
    except RecursionError:
        raise InputError(f"{path}: nested too deeply to read; flatten the file") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        raise InputError(f"{path}{where}: not valid YAML ({getattr(err, 'problem', err)}); "
                         "fix the syntax") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a YAML mapping of keys to values; check the file")
    return data


#: The keys of a result whose numbers commands and other tools read (``docs/conventions.md``;
#: each take's own under ``takes``). A parameter that is not determined is null, never NaN.
RESULT_NUMBERS = ("gyro_bias", "accel_bias", "T_marker_imu", "gravity_in_mocap", "time_offset",
                  "sigma", "gravity_magnitude", "effects", "noise")
TAKE_NUMBERS = ("time_offset", "gyro_bias", "accel_bias", "sigma")


def _first_non_finite(value: Any, where: str) -> str | None:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, dict):
        for k, v in value.items():
            found = _first_non_finite(v, f"{where}.{k}")
            if found:
                return found
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            found = _first_non_finite(v, f"{where}[{i}]")
            if found:
                return found
    elif isinstance(value, (int, float, np.number)) and not isinstance(value, bool):
        if not math.isfinite(float(value)):
            return f"{where} is {float(value)}"
    return None


#: The same for multipos intrinsics.
INTRINSICS_NUMBERS = ("accel_matrix", "accel_bias", "gyro_matrix", "gyro_bias", "g_sensitivity",
                      "sigma")


def non_finite(data: dict[str, Any], keys: tuple[str, ...] = RESULT_NUMBERS) -> str | None:
    """The first number under ``keys`` (a result's by default, and each take's) that is NaN
    or infinite, as ``"T_marker_imu.translation[0] is nan"``; None if all are finite."""
    for key in keys:
        found = _first_non_finite(data.get(key), key)
        if found:
            return found
    for i, take in enumerate(data.get("takes") or [] if keys == RESULT_NUMBERS else []):
        for key in TAKE_NUMBERS:
            found = _first_non_finite(take.get(key) if isinstance(take, dict) else None,
                                      f"takes[{i}].{key}")
            if found:
                return found
    return None


def save_result(path: str | Path, result: CalibrationResult) -> Path:
    """Write a calibration result (``docs/conventions.md`` keys first).

    Raises:
        ConvergenceError: a number of the result is NaN or infinite (nothing is written: a
            parameter the session does not determine is null with its reason, never NaN).
    """
    header = ("mocap-calib calibration result (SI units; 1-sigma under 'sigma').\n"
              "T_marker_imu is T_MI: x_M = R_MI x_I + p_MI. See docs/conventions.md.")
    data = result.to_dict()
    bad = non_finite(_plain(data))
    if bad:
        raise ConvergenceError(f"{path}: not written: {bad}, not a number a calibration can "
                               "have (no trustworthy solution); check the inputs, or report it "
                               "with the inputs if they are sound")
    return save_yaml(path, data, header)


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
    base = base or NoiseModel()
    values = base.to_dict()
    values.update(noise_values(path))
    return NoiseModel.from_dict(values)


def noise_values(path: str | Path) -> dict[str, float]:
    """The noise model's values a noise file gives (SI units), each a positive number.

    Raises:
        InputError: a value that is not a positive finite number, or no noise key at all.
    """
    data = load_yaml(path, "noise file")
    values = {}
    for key in (*NOISE_KEYS, "mocap_position_sigma", "mocap_rotation_sigma"):
        if key in data and data[key] is not None:
            try:
                if isinstance(data[key], bool):
                    raise TypeError("a truth value")
                v = float(data[key])
            except (TypeError, ValueError):
                raise InputError(f"{path}: '{key}' must be a number, got {data[key]!r}") from None
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{path}: '{key}' must be a positive number, got {v}")
            values[key] = v
    if not any(k in values for k in NOISE_KEYS):
        raise InputError(f"{path}: no noise keys found (expected Kalibr imu.yaml keys such as "
                         "gyroscope_noise_density); pass a noise file written by 'mocap-calib "
                         "allan' or Kalibr")
    return values


def load_plausible(path: str | Path) -> PlausibleLimits:
    """Plausibility limits: the defaults (``docs/diagnosis.md``) overridden by a YAML mapping,
    e.g. ``accel_bias: 2.0`` or ``effects: {gyro_g_sensitivity: {max: 5e-3}}``."""
    data = load_yaml(path, "plausibility limits file")
    try:
        limits = PlausibleLimits.from_dict(data)
    except KeyError as err:
        raise InputError(f"{path}: unknown limit '{err.args[0]}'; see docs/diagnosis.md for the "
                         "names") from None
    except (TypeError, ValueError, AttributeError) as err:
        raise InputError(f"{path}: limits must be numbers ({err}); see docs/diagnosis.md"
                         ) from None
    # A limit of NaN turns its check off without a word (every comparison with it is False).
    given = {k: v for k, v in vars(limits).items() if k != "effects"}
    given.update({f"effects.{n}.{k}": v for n, lim in limits.effects.items()
                  for k, v in lim.items()})
    for key, v in given.items():
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"{path}: '{key}' is {v:g}; a limit must be a finite positive "
                             "number (see docs/diagnosis.md)")
    for name, lim in limits.effects.items():
        if "min" in lim and "max" in lim and not lim["min"] < lim["max"]:
            raise InputError(f"{path}: 'effects.{name}' has min {lim['min']:g} not below max "
                             f"{lim['max']:g}; give min < max")
    return limits
