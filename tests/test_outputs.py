"""Outputs never touch inputs or each other: every command resolves what it will write and what
it reads before any work, and refuses a collision in one line that names both options.

The cases are derived from the commands themselves: every command of ``mocap-calib``, its
request's output options (declared with ``workflows.outputs.output``) against its input options
(every other path option), and its output options against each other. A new command, or a new
option, is covered without touching this file.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import io
import os
import typing
from dataclasses import MISSING
from pathlib import Path
from typing import Any

import pytest
import typer

from mocap_calib.cli.commands import COMMANDS, register
from mocap_calib.cli.main import app, main
from mocap_calib.errors import InputError
from mocap_calib.workflows.outputs import OUTPUT, OutputPlan, Product, write_products
from mocap_calib.workflows.requests import Leaf, from_flat, leaves

USER_BYTES = b"a file of the user's, not to be touched\n"


def _run(args: list[str]) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(args)
    return code, err.getvalue()


def _request_class(command: str) -> type:
    """The request dataclass a command module builds its command from."""
    module = importlib.import_module(f"mocap_calib.cli.commands.{command}")
    found = {v for v in vars(module).values() if isinstance(v, type)
             and dataclasses.is_dataclass(v) and v.__name__.endswith("Request")}
    assert len(found) == 1, f"{command}: request classes {found}"
    return found.pop()


def _field(cls: type, path: tuple[str, ...]) -> dataclasses.Field:
    hints = typing.get_type_hints(cls)
    f = next(f for f in dataclasses.fields(cls) if f.name == path[0])
    return f if len(path) == 1 else _field(hints[path[0]], path[1:])


def _is_path(leaf: Leaf) -> bool:
    t = leaf.type
    args = typing.get_args(t)
    return t is Path or Path in args or any(Path in typing.get_args(a) for a in args)


def _command_leaves(command: str) -> tuple[type, list[Leaf]]:
    """The request class and the options the command line offers."""
    register((command,))
    click_cmd = typer.main.get_command(app).commands[command]  # type: ignore[attr-defined]
    names = {p.name for p in click_cmd.params}
    cls = _request_class(command)
    return cls, [leaf for leaf in leaves(cls) if leaf.name in names]


def _filler(cls: type, leaf: Leaf, tmp: Path) -> Any:
    """A value for a required option that is not under test (an input file that exists, an
    output that does not)."""
    info = leaf.info
    if _is_path(leaf):
        p = tmp / f"given_{leaf.name}"
        if OUTPUT not in _field(cls, leaf.path).metadata:
            p.write_bytes(USER_BYTES)
        return p
    if info.choices:
        return info.choices[0]
    t = next((a for a in typing.get_args(leaf.type) if a is not type(None)), leaf.type)
    if t in (int, float):
        return t((info.lo or 0) + 1)
    return "x"


def _args(leaves_: list[Leaf], values: dict[str, Any]) -> list[str]:
    args: list[str] = []
    for leaf in leaves_:
        if leaf.name not in values:
            continue
        value = values[leaf.name]
        if leaf.info.argument:
            args.insert(0, str(value))
        else:
            args += [leaf.info.option_name(leaf.name), str(value)]
    return args


def _cases() -> list[tuple[str, str, str]]:
    """(command, output option, input option or another output option)."""
    cases = []
    for command in COMMANDS:
        cls, lv = _command_leaves(command)
        outs = [x for x in lv if OUTPUT in _field(cls, x.path).metadata]
        ins = [x for x in lv if _is_path(x) and OUTPUT not in _field(cls, x.path).metadata]
        cases += [(command, o.name, i.name) for o in outs for i in ins]
        files = [o for o in outs if _field(cls, o.path).metadata[OUTPUT] == "file"]
        cases += [(command, a.name, b.name) for k, a in enumerate(files) for b in files[:k]]
    return cases


CASES = _cases()


def test_the_cases_cover_every_command_that_writes() -> None:
    commands = {c for c, _, _ in CASES}
    assert commands >= {"calibrate", "diagnose", "groundtruth", "export", "multipos", "allan",
                        "drift", "batch"}, commands
    assert len(CASES) > 60


def _product_of(cls: type, values: dict[str, Any], leaf: Leaf) -> Path:
    """Where an output option's first file goes (its value, or for a folder or a prefix the
    first file the command's plan names for it)."""
    request = from_flat(cls, values, check=False)
    option = leaf.info.option_name(leaf.name)
    plan = request.plan() if hasattr(request, "plan") else OutputPlan.of(request)
    return next(o.path for o in plan.outputs if o.option == option and not o.role)


@pytest.mark.parametrize("command,out_name,other_name", CASES,
                         ids=[f"{c}:{o}={i}" for c, o, i in CASES])
def test_an_output_that_is_an_input_or_another_output_is_refused(
        command: str, out_name: str, other_name: str, tmp_path: Path) -> None:
    cls, lv = _command_leaves(command)
    by_name = {x.name: x for x in lv}
    out_leaf, other = by_name[out_name], by_name[other_name]
    values = {x.name: _filler(cls, x, tmp_path) for x in lv if x.default is MISSING}
    kind = _field(cls, out_leaf.path).metadata[OUTPUT]
    values[out_name] = tmp_path / ("shared.dat" if kind == "file" else "shared")
    target = _product_of(cls, values, out_leaf)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(USER_BYTES)
    values[other_name] = target
    code, err = _run([command, *_args(lv, values)])
    last = err.strip().splitlines()[-1] if err.strip() else ""
    assert code == 2, err
    assert last.startswith("error: ") and "Traceback" not in err, err
    words = [out_leaf.info.option_name(out_name), other.info.option_name(other_name)]
    words.append("is also" if OUTPUT in _field(cls, other.path).metadata else "is the input")
    for w in words:
        assert w in last, last
    assert target.read_bytes() == USER_BYTES


@pytest.fixture()
def session(tmp_path: Path) -> Path:
    """A mav0 folder (a few rows suffice: every refusal comes before the files are read)."""
    root = tmp_path / "s" / "mav0"
    for sensor in ("imu0", "vicon0"):
        (root / sensor).mkdir(parents=True)
        (root / sensor / "data.csv").write_bytes(USER_BYTES)
    return tmp_path / "s"


def test_an_output_through_links_is_refused(session: Path, tmp_path: Path) -> None:
    imu = session / "mav0" / "imu0" / "data.csv"
    mocap = session / "mav0" / "vicon0" / "data.csv"
    (tmp_path / "link.csv").symlink_to(imu)
    os.link(imu, tmp_path / "hard.csv")
    (tmp_path / "linked_folder").symlink_to(session / "mav0")
    for out, how in ((tmp_path / "link.csv", "through a symbolic link"),
                     (tmp_path / "hard.csv", "a hard link to it"),
                     (tmp_path / "linked_folder" / "imu0" / "data.csv",
                      "through a symbolic link")):
        code, err = _run(["calibrate", "--imu", str(imu), "--mocap", str(mocap), "--out",
                          str(out)])
        assert code == 2 and how in err and "is the input --imu" in err, err
    assert imu.read_bytes() == USER_BYTES


def test_an_output_onto_a_file_of_an_input_folder_is_refused(session: Path) -> None:
    target = session / "mav0" / "vicon0" / "data.csv"
    code, err = _run(["calibrate", str(session), "--out", str(target)])
    assert code == 2, err
    assert "is the input MAV0 (its file mav0/vicon0/data.csv)" in err, err
    assert target.read_bytes() == USER_BYTES
    # Beside the recording (not one of its sensor files) a result is fine: the plan passes.
    from mocap_calib.workflows.calibrate import CalibrateRequest

    request = from_flat(CalibrateRequest, {"mav0": session, "out": session / "calib.yaml"})
    request.plan().check()


def test_groundtruth_sidecar_and_imu_tk_files_are_planned(tmp_path: Path) -> None:
    from mocap_calib.workflows.export import ExportRequest
    from mocap_calib.workflows.groundtruth import GroundtruthRequest

    calib = tmp_path / "calib.yaml"
    calib.write_bytes(USER_BYTES)
    gt = from_flat(GroundtruthRequest, {"imu": [tmp_path / "a"], "mocap": [tmp_path / "b"],
                                        "calibration": calib, "out": tmp_path / "calib.csv"})
    with pytest.raises(InputError, match=r"--out \(its sidecar\) .*calib.yaml: is the input "
                                         "--calibration"):
        gt.plan().check()
    intr = tmp_path / "imu_acc.calib"
    intr.write_bytes(USER_BYTES)
    ex = from_flat(ExportRequest, {"calibration": intr, "to": "imu_tk",
                                   "out": tmp_path / "imu"})
    with pytest.raises(InputError, match="imu_acc.calib: is the input CALIBRATION"):
        ex.plan().check()


def test_devices_may_take_several_outputs(tmp_path: Path) -> None:
    from mocap_calib.workflows.calibrate import CalibrateRequest

    request = from_flat(CalibrateRequest, {"mav0": [tmp_path], "out": Path("/dev/null"),
                                           "report": Path("/dev/null")})
    request.plan().check()


def test_a_batch_session_result_onto_another_session_input_is_refused(session: Path,
                                                                       tmp_path: Path) -> None:
    out = tmp_path / "out"
    (out / "b").mkdir(parents=True)
    prior = out / "b" / "calib.yaml"
    prior.write_bytes(USER_BYTES)
    manifest = tmp_path / "m.yaml"
    manifest.write_text(f"sessions:\n  - {{id: a, imu_id: x, date: 2024-01-01, mav0: {session},"
                        f" prior: {prior}}}\n  - {{id: b, imu_id: x, date: 2024-01-02, mav0: "
                        f"{session}}}\n")
    code, err = _run(["batch", str(manifest), "--out", str(out), "--quiet"])
    assert code == 2, err
    assert "--out (session 'b')" in err and "session 'a' prior" in err, err
    assert prior.read_bytes() == USER_BYTES


def test_write_products_writes_the_result_last() -> None:
    order: list[str] = []
    products = [Product(name, Path(name), lambda n=name: order.append(n))
                for name in ("result.yaml", "view.rrd", "page.html")]
    written = write_products([products[0], None, *products[1:]])
    assert order == ["view.rrd", "page.html", "result.yaml"]
    assert [p.option for p in written] == ["result.yaml", "view.rrd", "page.html"]


DEV_FULL = Path("/dev/full")


@pytest.mark.slow
@pytest.mark.skipif(not DEV_FULL.exists(), reason="no /dev/full here")
def test_diagnose_writes_its_report_after_its_recording(tmp_path: Path) -> None:
    """The report YAML is the result: a recording that cannot be written leaves none (it was
    written before the recording)."""
    from mocap_calib.workflows.simulate import simulate_to_folder

    s = tmp_path / "s"
    simulate_to_folder(s, seed=5, duration=30.0)
    report = tmp_path / "report.yaml"
    code, err = _run(["diagnose", str(s), "--out", str(report), "--rrd", str(DEV_FULL), "-q"])
    assert code == 2 and "/dev/full: cannot write" in err, err
    assert not report.exists()


# --- a read-only file system ------------------------------------------------------------------

def _read_only(monkeypatch: pytest.MonkeyPatch, root: Path) -> None:
    """Make ``root`` behave as a read-only mount: every call that would change something
    under it fails with EROFS, the removal of a file that is not there included (the kernel
    checks the mount before it looks the name up; Python's ``missing_ok`` catches only
    ENOENT). A chmod 0555 folder would not do here: the tests may run as root."""
    import builtins
    import errno

    top = os.path.realpath(root)

    def under(p: Any) -> bool:
        try:
            real = os.path.realpath(os.fsdecode(p))
        except TypeError:
            return False
        return real == top or real.startswith(top + os.sep)

    def refuse(p: Any) -> None:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.fsdecode(p))

    def wrap(fn: Any, n_paths: int = 1) -> Any:
        def call(*a: Any, **k: Any) -> Any:
            if any(under(x) for x in a[:n_paths]):
                refuse(a[0])
            return fn(*a, **k)
        return call

    real_open, real_os_open = builtins.open, os.open
    writes = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_APPEND

    def os_open(path: Any, flags: int, *a: Any, **k: Any) -> int:
        if flags & writes and under(path):
            refuse(path)
        return real_os_open(path, flags, *a, **k)

    def py_open(file: Any, mode: str = "r", *a: Any, **k: Any) -> Any:
        if not isinstance(file, int) and any(c in mode for c in "wxa+") and under(file):
            refuse(file)
        return real_open(file, mode, *a, **k)

    monkeypatch.setattr(os, "open", os_open)
    for name in ("mkdir", "unlink", "remove", "rmdir", "chmod"):
        monkeypatch.setattr(os, name, wrap(getattr(os, name)))
    for name in ("replace", "rename"):
        monkeypatch.setattr(os, name, wrap(getattr(os, name), 2))
    monkeypatch.setattr(builtins, "open", py_open)
    monkeypatch.setattr(io, "open", py_open)


def _ro_cases() -> list[tuple[str, str]]:
    out = []
    for command in COMMANDS:
        cls, lv = _command_leaves(command)
        out += [(command, x.name) for x in lv if OUTPUT in _field(cls, x.path).metadata]
    return out


RO_CASES = _ro_cases()


@pytest.mark.parametrize("command,out_name", RO_CASES, ids=[f"{c}:{o}" for c, o in RO_CASES])
def test_an_output_on_a_read_only_file_system_is_one_line(
        command: str, out_name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every command, every output option: refused before any work with the file system's
    own reason (this raised OSError, exit 70, from the clean-up of the write probe)."""
    cls, lv = _command_leaves(command)
    values = {x.name: _filler(cls, x, tmp_path) for x in lv if x.default is MISSING}
    ro = tmp_path / "read_only"
    ro.mkdir()
    values[out_name] = ro / "out.dat"
    _read_only(monkeypatch, ro)
    code, err = _run([command, *_args(lv, values)])
    assert code == 2, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("error: ") and "Read-only file system" in last, err
    assert list(ro.iterdir()) == []


def test_a_write_on_a_read_only_file_system_is_one_line(tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    from mocap_calib.io.atomic import check_writable, write_text

    _read_only(monkeypatch, tmp_path)
    for call in (lambda: write_text(tmp_path / "a.yaml", "x: 1\n"),
                 lambda: check_writable(tmp_path / "b.yaml"),
                 lambda: write_text(tmp_path / "new" / "c.yaml", "x: 1\n")):
        with pytest.raises(InputError, match="cannot write \\(Read-only file system\\)"):
            call()


def test_an_output_in_a_pseudo_file_system_is_one_line(tmp_path: Path) -> None:
    """Without the monkeypatching: /sys refuses new files even to root (EACCES, EPERM)."""
    sys_dir = Path("/sys")
    if not sys_dir.is_dir():
        pytest.skip("no /sys here")
    calib = tmp_path / "calib.yaml"
    calib.write_bytes(USER_BYTES)
    for args in (["export", str(calib), "--to", "px4", "--out", "/sys/mocap-calib.params"],
                 ["simulate", "/sys/mocap-calib-sim"],
                 ["export", str(calib), "--to", "imu_tk", "--out", "/sys/mocap-calib"]):
        code, err = _run(args)
        assert code == 2 and "cannot write" in err.strip().splitlines()[-1], err


def test_an_output_inside_another_output_file_is_refused(tmp_path: Path) -> None:
    from mocap_calib.workflows.calibrate import CalibrateRequest

    for out, html in ((tmp_path / "r.yaml", tmp_path / "r.yaml" / "page.html"),
                      (tmp_path / "r.yaml" / "calib.yaml", tmp_path / "r.yaml")):
        request = from_flat(CalibrateRequest, {"mav0": [tmp_path / "s"], "out": out,
                                               "html": html})
        with pytest.raises(InputError, match="would be written inside"):
            request.plan().check()
