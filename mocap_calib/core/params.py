"""Options as typed fields: default, help, unit and allowed values of each in one place.

A request dataclass declares its options with :func:`param`; the command line, the batch
manifest and the Python API are derived from those declarations, and :func:`check_options`
checks every value the same way (NaN, inf, range, choices), with one line that names the
option, what it is for and what it accepts.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import MISSING, dataclass
from typing import Any

from mocap_calib.errors import InputError


@dataclass(frozen=True)
class ParamInfo:
    """What the surfaces need to know of one option.

    Attributes:
        help: what the option is for (one sentence, no trailing period needed).
        unit: unit of the value (shown in help and errors).
        lo, hi: allowed range (inclusive unless ``lo_open`` / ``hi_open``); ``also``: single
            values allowed outside it (e.g. 0 for "off").
        choices: the allowed strings.
        parse: turns the command-line string into the field's type (e.g. ``Model.parse``).
        metavar: how the value is shown in help.
        decls: option names (default ``--<name-with-dashes>``), e.g. ``("--quiet", "-q")``.
        argument: a positional argument instead of an option.
        show_default: show the default in help.
    """

    help: str
    unit: str | None = None
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    also: tuple[float, ...] = ()
    choices: tuple[str, ...] | None = None
    parse: Callable[[str], Any] | None = None
    metavar: str | None = None
    decls: tuple[str, ...] = ()
    argument: bool = False
    show_default: bool = True

    def option_name(self, name: str) -> str:
        """The name a user types (``--keyframe-spacing``), or the argument's name."""
        if self.argument:
            return name.upper()
        # A flag pair (``--noise-from-data/--fixed-noise``) is named by its first form.
        return self.decls[0].split("/")[0] if self.decls else "--" + name.replace("_", "-")

    def allowed(self) -> str:
        """The allowed values in words (empty when anything of the type goes)."""
        u = f" {self.unit}" if self.unit else ""
        if self.choices:
            return "one of " + ", ".join(self.choices)
        if self.lo is None and self.hi is None:
            return "a finite number" if self.unit or self.also else ""
        also = "".join(f"{_fmt(a)} or " for a in self.also)
        if self.lo is not None and self.hi is not None:
            if not (self.lo_open or self.hi_open):
                return f"{also}between {_fmt(self.lo)} and {_fmt(self.hi)}{u}"
            lo = "above" if self.lo_open else "at least"
            hi = "below" if self.hi_open else "at most"
            return f"{also}{lo} {_fmt(self.lo)} and {hi} {_fmt(self.hi)}{u}"
        if self.lo is not None:
            return f"{also}{'above' if self.lo_open else 'at least'} {_fmt(self.lo)}{u}"
        return f"{also}{'below' if self.hi_open else 'at most'} {_fmt(self.hi)}{u}"


def _fmt(x: float) -> str:
    return f"{x:g}"


def param(default: Any = MISSING, help: str = "", *, default_factory: Any = MISSING,
          **info: Any) -> Any:
    """A dataclass field that is an option (see :class:`ParamInfo` for ``info``)."""
    meta = {"param": ParamInfo(help=help, **info)}
    if default_factory is not MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def group(cls: type, title: str) -> Any:
    """A field holding a group of options (another request dataclass), shown under
    ``title``."""
    return dataclasses.field(default_factory=cls, metadata={"group": title})


def param_info(f: dataclasses.Field) -> ParamInfo | None:
    return f.metadata.get("param")


def check_value(name: str, value: Any, info: ParamInfo) -> None:
    """Raise :class:`InputError` naming the option when ``value`` is not allowed."""
    if value is None or isinstance(value, bool):
        return
    values: Sequence[Any] = value if isinstance(value, (list, tuple)) else [value]
    for v in values:
        if isinstance(v, str) and info.choices is not None and v not in info.choices:
            _refuse(name, v, info)
        if isinstance(v, (int, float)):
            x = float(v)
            if not math.isfinite(x):
                _refuse(name, v, info)
            if x in info.also:
                continue
            if info.lo is not None and (x < info.lo or (info.lo_open and x == info.lo)):
                _refuse(name, v, info)
            if info.hi is not None and (x > info.hi or (info.hi_open and x == info.hi)):
                _refuse(name, v, info)


def _refuse(name: str, value: Any, info: ParamInfo) -> None:
    allowed = info.allowed() or "a finite value"
    raise InputError(f"{info.option_name(name)} {value}: must be {allowed} ({info.help})")


def check_options(obj: Any) -> None:
    """Check every option of a request dataclass (and of the requests nested in it)."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        info = param_info(f)
        if info is not None:
            check_value(f.name, value, info)
        elif dataclasses.is_dataclass(value) and not isinstance(value, type):
            check_options(value)
