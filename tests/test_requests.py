"""One typed request per command: the command line is derived from it (every option of
``--help`` is a field of the request and every field an option), values are checked from one
place (NaN, inf, ranges, choices: one line naming the option), a repeated single-value option
is refused, and the commands that read a session take every input option of ``calibrate``."""

from __future__ import annotations

import math

import pytest
import typer

from mocap_calib.cli.main import app, main
from mocap_calib.workflows.requests import from_flat, leaves

COMMANDS = ("simulate", "calibrate", "diagnose", "view", "multipos", "allan", "drift",
            "export", "groundtruth", "batch", "compile")


def _commands() -> dict:
    main(["--help"])  # registers every command
    return typer.main.get_command(app).commands


def _request_of(name: str) -> tuple[type, tuple[str, ...]]:
    """The request class and excluded fields of a command (as registered)."""
    from mocap_calib.batch.runner import BatchRequest
    from mocap_calib.workflows.calibrate import CalibrateRequest
    from mocap_calib.workflows.compile import CompileRequest
    from mocap_calib.workflows.diagnose import NOT_OPTIONS, DiagnoseRequest
    from mocap_calib.workflows.export import ExportRequest
    from mocap_calib.workflows.groundtruth import GroundtruthRequest
    from mocap_calib.workflows.imu.allan import AllanRequest
    from mocap_calib.workflows.imu.drift import DriftRequest
    from mocap_calib.workflows.imu.imu_input import MULTIPOS_ONLY
    from mocap_calib.workflows.imu.multipos import MultiposRequest
    from mocap_calib.workflows.simulate import SimulateRequest
    from mocap_calib.workflows.view import ViewRequest

    return {"simulate": (SimulateRequest, ()), "calibrate": (CalibrateRequest, ()),
            "diagnose": (DiagnoseRequest, NOT_OPTIONS), "view": (ViewRequest, ()),
            "multipos": (MultiposRequest, ()), "allan": (AllanRequest, MULTIPOS_ONLY),
            "drift": (DriftRequest, MULTIPOS_ONLY), "export": (ExportRequest, ()),
            "groundtruth": (GroundtruthRequest, ()), "batch": (BatchRequest, ()),
            "compile": (CompileRequest, ())}[name]


def test_every_command_has_a_request() -> None:
    assert set(_commands()) == set(COMMANDS)


@pytest.mark.parametrize("name", COMMANDS)
def test_help_is_the_request(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    """The options --help shows are exactly the request's fields, with their help text."""
    cls, exclude = _request_of(name)
    fields = [leaf for leaf in leaves(cls) if leaf.name not in exclude]
    names = [leaf.name for leaf in fields]
    assert len(names) == len(set(names)), f"{name}: option names repeat: {names}"
    cmd = _commands()[name]
    params = {p.name: p for p in cmd.params if p.name != "help"}
    assert set(params) == set(names)
    assert main([name, "--help"]) == 0
    text = " ".join(capsys.readouterr().out.replace("│", " ").split())
    for leaf in fields:
        p = params[leaf.name]
        if not leaf.info.argument:
            assert leaf.info.option_name(leaf.name) in p.opts, (name, leaf.name, p.opts)
            assert leaf.info.option_name(leaf.name) in text, (name, leaf.name)
        words = leaf.info.help.split()[:4]  # the help's start shows (capitalised)
        assert " ".join(words[1:]) in text, (name, leaf.name)


@pytest.mark.parametrize("name", [None, *COMMANDS])
def test_flags_show_no_type(name: str | None, capsys: pytest.CaptureFixture[str]) -> None:
    """A flag takes no value, so --help shows none for it: the commands' flags and --help
    itself, on the app's page and on every command's."""
    assert main([*([name] if name else []), "--help"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines()
            if "--help" in line or "--quiet" in line]
    assert rows and not [r for r in rows if "<bool>" in r], rows


def _numeric(name: str) -> list:
    cls, exclude = _request_of(name)
    out = []
    for leaf in leaves(cls):
        base = [a for a in getattr(leaf.type, "__args__", (leaf.type,)) if a is not type(None)]
        if leaf.name not in exclude and base and base[0] in (int, float) \
                and not leaf.repeatable:
            out.append(leaf)
    return out


@pytest.mark.parametrize("name", COMMANDS)
def test_nan_inf_and_out_of_range_are_refused_naming_the_option(name: str) -> None:
    cls, _ = _request_of(name)
    required = {leaf.name: leaf.default for leaf in leaves(cls)}
    base = {k: ("x" if k in ("calibration", "manifest", "recording", "out_dir", "to")
                else None) for k, v in required.items() if v is not None and
            getattr(v, "__class__", None).__name__ == "_MISSING_TYPE"}
    if "to" in base:
        base["to"] = "kalibr"
    checked = 0
    for leaf in _numeric(name):
        values = [math.nan, math.inf, -math.inf] if leaf.type is float or float in getattr(
            leaf.type, "__args__", ()) else []
        if leaf.info.lo is not None:
            values.append(leaf.info.lo - 1e3)
        if leaf.info.hi is not None:
            values.append(leaf.info.hi + 1e3)
        for v in values:
            with pytest.raises(Exception) as err:
                from_flat(cls, {**base, leaf.name: v})
            msg = str(err.value)
            assert leaf.info.option_name(leaf.name) in msg and "must be" in msg, msg
            assert leaf.info.help.split()[0] in msg, msg  # says what the option is for
            checked += 1
    assert checked or not _numeric(name)


def test_nan_through_the_cli_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["calibrate", "x", "--time-offset", "nan"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "--time-offset nan: must be a finite number" in err


@pytest.mark.parametrize("args,option", [
    (["calibrate", "x", "--gravity", "9.8", "--gravity", "9.81"], "--gravity"),
    (["calibrate", "x", "--window=4", "--window", "5"], "--window"),
    (["diagnose", "x", "--alpha", "0.01", "--alpha", "0.05"], "--alpha"),
    (["allan", "--imu", "a", "--imu", "b"], "--imu"),
    (["export", "c.yaml", "--to", "kalibr", "--to", "vins"], "--to"),
])
def test_a_repeated_single_value_option_is_refused(args: list[str], option: str,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert f"error: {option} is given more than once" in err


def test_repeatable_options_may_repeat(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["calibrate", "--imu", "a", "--mocap", "b", "--prior", "p", "--prior", "q"])
    err = capsys.readouterr().err
    assert "more than once" not in err and code == 2  # the files do not exist


@pytest.mark.parametrize("name", ("diagnose", "groundtruth", "batch"))
def test_session_commands_take_every_calibrate_input_option(name: str) -> None:
    from mocap_calib.batch.manifest import ARG_KEYS
    from mocap_calib.workflows.calibrate import CalibrateRequest
    from mocap_calib.workflows.session import InputSpec, NoiseSpec

    inputs = {leaf.name for leaf in leaves(InputSpec)} | {leaf.name for leaf in
                                                          leaves(NoiseSpec)}
    if name == "batch":  # the sessions' options are the manifest's keys
        assert inputs <= set(ARG_KEYS)
        assert {leaf.name for leaf in leaves(CalibrateRequest)} - set(ARG_KEYS) == {
            "out", "report", "rrd", "html", "quiet"}
        return
    params = {p.name for p in _commands()[name].params}
    assert inputs <= params, inputs - params
    if name == "diagnose":
        assert {"time_offset", "max_offset", "start", "end", "start_model"} <= params
