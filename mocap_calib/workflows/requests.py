"""One typed request per command: what the command line, the batch manifest and the Python
API are derived from.

A request is a dataclass whose fields are options (declared with
:func:`mocap_calib.core.params.param`) or groups of options (another such dataclass, declared
with :func:`mocap_calib.core.params.group`). :func:`leaves` lists the options of a request in order,
groups (their names are unique across a request: a test checks it); :func:`from_flat` builds
a request from values by those names, as the command line and a manifest give them, and checks
every value (:func:`mocap_calib.core.params.check_options`).
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import MISSING, dataclass
from typing import Any

from mocap_calib.core.params import ParamInfo, check_options, param_info
from mocap_calib.errors import InputError


@dataclass(frozen=True)
class Leaf:
    """One option of a request.

    Attributes:
        name: its name (``keyframe_spacing``: ``--keyframe-spacing``, manifest key
            ``keyframe_spacing``).
        path: the field names from the request down to it.
        type: the field's type (resolved).
        default: its default value.
        info: help, unit, allowed values.
        panel: the group it is shown under (None: the command's own options).
    """

    name: str
    path: tuple[str, ...]
    type: Any
    default: Any
    info: ParamInfo
    panel: str | None

    @property
    def repeatable(self) -> bool:
        """Given once per value (a tuple or list of values; not one parsed string)."""
        return typing.get_origin(self.type) in (tuple, list) and self.info.parse is None


def _default(f: dataclasses.Field) -> Any:
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:
        return f.default_factory()
    return MISSING


def leaves(cls: type, path: tuple[str, ...] = (), panel: str | None = None) -> list[Leaf]:
    """Every option of request class ``cls``, groups flattened, in declaration order."""
    hints = typing.get_type_hints(cls)
    out: list[Leaf] = []
    for f in dataclasses.fields(cls):
        info = param_info(f)
        if info is not None:
            out.append(Leaf(f.name, (*path, f.name), hints[f.name], _default(f), info, panel))
        elif "group" in f.metadata:
            out.extend(leaves(hints[f.name], (*path, f.name), f.metadata["group"]))
    return out


def from_flat(cls: type, values: dict[str, Any], check: bool = True) -> Any:
    """A request of class ``cls`` from option values by name (missing ones: their defaults).
    Strings are parsed where the option says how (``--model``), sequences become tuples."""
    by_path = {leaf.path: leaf for leaf in leaves(cls)}

    def build(c: type, path: tuple[str, ...]) -> Any:
        hints = typing.get_type_hints(c)
        kwargs = {}
        for f in dataclasses.fields(c):
            p = (*path, f.name)
            if p in by_path:
                if f.name not in values:
                    continue
                kwargs[f.name] = _coerce(values[f.name], by_path[p])
            elif "group" in f.metadata:
                kwargs[f.name] = build(hints[f.name], p)
        return c(**kwargs)

    request = build(cls, ())
    if check:
        check_options(request)
    return request


def _coerce(value: Any, leaf: Leaf) -> Any:
    if value is None:
        return leaf.default if leaf.repeatable else None
    if leaf.info.parse is not None and isinstance(value, str):
        try:
            return leaf.info.parse(value)
        except InputError as err:  # the line names the option, as a range check's does
            raise InputError(f"{leaf.info.option_name(leaf.name)}: {err}") from None
    if leaf.repeatable:
        return tuple(value) if isinstance(value, (list, tuple)) else (value,)
    return value


def to_flat(request: Any) -> dict[str, Any]:
    """Option values by name (the inverse of :func:`from_flat`)."""
    out = {}
    for leaf in leaves(type(request)):
        obj = request
        for name in leaf.path:
            obj = getattr(obj, name)
        out[leaf.name] = obj
    return out
