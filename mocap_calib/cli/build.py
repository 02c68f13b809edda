"""Commands from requests: every option of a command is a field of its request dataclass
(:mod:`mocap_calib.workflows.requests`), so its name, type, default, help, unit and allowed
values are declared once. :func:`add_command` turns a request into a typer command whose
handler receives the checked request; :func:`repeated_options` finds single-value options
given more than once (click keeps the last one silently)."""

from __future__ import annotations

import inspect
import typing
from collections.abc import Callable, Sequence
from dataclasses import MISSING
from typing import Annotated, Any, Literal

import typer

from mocap_calib.cli.common import Command
from mocap_calib.workflows.requests import Leaf, from_flat, leaves

#: Choices longer than this (joined) are listed in the help text instead of the type column,
#: which would otherwise squeeze every help text of the command.
LONG_CHOICES = 16


def _long_choices(leaf: Leaf) -> bool:
    return bool(leaf.info.choices) and len("|".join(leaf.info.choices)) > LONG_CHOICES


def _help(leaf: Leaf) -> str:
    info = leaf.info
    text = info.help[:1].upper() + info.help[1:]
    if _long_choices(leaf):
        text += "; one of " + ", ".join(info.choices or ())
    extra = [x for x in (info.unit, None if info.choices else info.allowed()) if x]
    if extra and info.unit and info.allowed().endswith(info.unit):
        extra = [info.allowed()]
    return text + (f" ({'; '.join(extra)})" if extra else "") + "."


def _cli_type(leaf: Leaf) -> Any:
    """The type typer parses the option as."""
    t = leaf.type
    if leaf.repeatable:
        (item, *_) = typing.get_args(t)
        return list[item] | None  # type: ignore[valid-type]
    optional = type(None) in typing.get_args(t)
    base = next((a for a in typing.get_args(t) if a is not type(None)), t) if optional else t
    if leaf.info.parse is not None:
        base = str
    if leaf.info.choices:
        base = Literal[leaf.info.choices]  # type: ignore[valid-type]
    return base | None if optional else base


def _parameter(leaf: Leaf) -> inspect.Parameter:
    info = leaf.info
    kwargs: dict[str, Any] = {"help": _help(leaf), "show_default": info.show_default}
    if leaf.panel:
        kwargs["rich_help_panel"] = leaf.panel
    is_flag = leaf.type is bool
    if info.metavar is not None:
        kwargs["metavar"] = info.metavar
    elif _long_choices(leaf):
        kwargs["metavar"] = "NAME"
    elif is_flag:
        kwargs["metavar"] = ""
    if info.argument:
        marker = typer.Argument(**kwargs)
    else:
        marker = typer.Option(*info.decls, **kwargs)
    default = leaf.default
    if default is MISSING:
        default = ...  # required
    elif leaf.repeatable:
        default = None
    elif info.parse is not None and default is not None:
        # Shown and parsed back as the user would write it (effect names joined by '+').
        default = "+".join(default) if isinstance(default, tuple) else str(default)
    return inspect.Parameter(leaf.name, inspect.Parameter.KEYWORD_ONLY, default=default,
                             annotation=Annotated[_cli_type(leaf), marker])


def add_command(app: typer.Typer, name: str, request_cls: type,
                handler: Callable[[Any], None], *, help: str, epilog: str = "",
                exclude: Sequence[str] = ()) -> None:
    """Register command ``name``: its options are the leaves of ``request_cls`` (less
    ``exclude``); the handler gets the request built from them and checked."""
    params = [_parameter(leaf) for leaf in leaves(request_cls) if leaf.name not in exclude]

    def command(**values: Any) -> None:
        handler(from_flat(request_cls, values))

    command.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    command.__annotations__ = {p.name: p.annotation for p in params}
    command.__name__ = name
    app.command(name=name, help=help, epilog=epilog, cls=Command)(command)


def option_names(leaf: Leaf) -> tuple[str, ...]:
    return leaf.info.decls or ("--" + leaf.name.replace("_", "-"),)


def repeated_options(command: Any, args: Sequence[str]) -> list[str]:
    """Options of the click ``command`` that take one value and appear more than once in
    ``args`` (``--opt value`` or ``--opt=value``)."""
    single: dict[str, str] = {}
    for p in getattr(command, "params", []):
        if getattr(p, "multiple", False) or getattr(p, "is_flag", False) \
                or getattr(p, "count", False) or not getattr(p, "opts", None):
            continue
        for o in (*p.opts, *p.secondary_opts):
            single[o] = p.opts[0]
    seen: dict[str, int] = {}
    for a in args:
        if a == "--":
            break
        key = a.split("=", 1)[0] if a.startswith("--") else a
        if key in single:
            seen[single[key]] = seen.get(single[key], 0) + 1
    return [o for o, n in seen.items() if n > 1]

