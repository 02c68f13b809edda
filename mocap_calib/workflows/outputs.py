"""What a command writes and reads, resolved before any work, and the one way it writes.

Every option that names something a command writes is declared with :func:`output` (a
:func:`~mocap_calib.core.params.param` that says so); every other path option is an input.
:meth:`OutputPlan.of` collects both from a request (a command's request may add what its
options expand to: a sidecar, the files of an output folder, the sessions of a manifest), and
:meth:`OutputPlan.check` refuses, in one line naming the options, the paths and the fix:

- an output that is an input, through symbolic links (``os.path.realpath``) or as a hard link
  to it (same device and inode), or that is one of the files an input folder holds (a mav0
  folder's sensor files, a bag folder's files);
- two outputs that are one file, or an output inside another output file;
- an output that cannot be written (:func:`~mocap_calib.io.atomic.check_writable`).

Devices and pipes (``/dev/null``, ``/dev/stdout``) are written into, never replaced, and may
be named by several outputs. :func:`write_products` writes a command's files, its result file
last, so that a run stopped or failed while writing leaves no result that looks finished.
"""

from __future__ import annotations

import dataclasses
import os
import stat
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mocap_calib.core.params import ParamInfo, param_info
from mocap_calib.errors import InputError
from mocap_calib.io.atomic import check_writable
from mocap_calib.io.formats.euroc import find_mav0

#: Field metadata key of an output option; its value is the output's kind.
OUTPUT = "output"
#: ``file``: the path is the file written; ``folder``: files are written inside it; ``prefix``:
#: files named by appending to it (their paths come from the request's plan).
KINDS = ("file", "folder", "prefix")


def output(default: Any, help: str = "", *, kind: str = "file", **info: Any) -> Any:
    """A request field that is an option naming what the command writes (see :data:`KINDS`)."""
    if kind not in KINDS:
        raise ValueError(f"output kind {kind!r}: one of {KINDS}")
    return dataclasses.field(default=default,
                             metadata={"param": ParamInfo(help=help, **info), OUTPUT: kind})


def output_kind(f: dataclasses.Field) -> str | None:
    return f.metadata.get(OUTPUT)


@dataclass(frozen=True)
class Named:
    """A path and the option that names it (``--out``, ``MAV0``); ``role`` says what the path
    is to the option when it is not the option's value itself (``its sidecar``)."""

    option: str
    path: Path
    role: str = ""

    def __str__(self) -> str:
        return f"{self.option} ({self.role}) {self.path}" if self.role else \
            f"{self.option} {self.path}"


def request_options(request: Any) -> Iterator[tuple[dataclasses.Field, ParamInfo, Any]]:
    """Every option of a request (groups flattened) with its declaration and value."""
    for f in dataclasses.fields(request):
        value = getattr(request, f.name)
        info = param_info(f)
        if info is not None:
            yield f, info, value
        elif dataclasses.is_dataclass(value) and not isinstance(value, type):
            yield from request_options(value)


def _paths(value: Any) -> list[Path]:
    items = value if isinstance(value, (list, tuple)) else [value]
    return [Path(v) for v in items if isinstance(v, (str, Path)) and str(v)]


def _folder_files(folder: Path) -> list[Path]:
    """The files a reader takes from an input folder: a mav0 folder's sensor files
    (``imu0/data.csv``, ``vicon0/sensor.yaml``, ...), else the folder's own files (a ROS 2
    bag)."""
    try:
        roots = [p for p in find_mav0(folder).iterdir() if p.is_dir()]
    except (InputError, OSError):
        roots = [folder]
    files = []
    for root in roots:
        try:
            files += [p for p in root.iterdir() if p.is_file()]
        except OSError:
            continue
    return files


def _special(path: Path) -> bool:
    """A device, pipe or socket (or a stream's name): written into, never replaced."""
    if os.path.abspath(path).startswith(("/dev/", "/proc/")):
        return True
    try:
        mode = path.stat().st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


@dataclass(frozen=True)
class _Resolved:
    named: Named  # as the message shows it
    path: Path  # the file compared (a file inside an input folder: that file)
    real: str  # through symbolic links
    inode: tuple[int, int] | None  # (device, inode) of an existing regular file

    @classmethod
    def of(cls, named: Named, path: Path | None = None) -> _Resolved:
        path = named.path if path is None else path
        real = os.path.realpath(path)
        try:
            st = os.stat(real)
            inode = (st.st_dev, st.st_ino) if stat.S_ISREG(st.st_mode) else None
        except OSError:
            inode = None
        return cls(named, path, real, inode)

    def how(self, other: _Resolved) -> str:
        """How ``self`` reaches ``other``'s file, for the message."""
        if self.real != other.real:
            return " (a hard link to it)"
        if os.path.abspath(self.path) != os.path.abspath(other.path):
            return " (through a symbolic link)"
        return ""


@dataclass
class OutputPlan:
    """The files a command will write and the paths it will read (see the module doc)."""

    outputs: list[Named] = field(default_factory=list)
    inputs: list[Named] = field(default_factory=list)

    @classmethod
    def of(cls, request: Any, outputs: Sequence[Named] = (),
           inputs: Sequence[Named] = ()) -> OutputPlan:
        """The request's ``file`` outputs and every other path option as an input, plus
        ``outputs`` and ``inputs`` (what the command's folder and prefix outputs and derived
        files are)."""
        plan = cls()
        for f, info, value in request_options(request):
            kind = output_kind(f)
            named = [Named(info.option_name(f.name), p) for p in _paths(value)]
            if kind is None:
                plan.inputs += named
            elif kind == "file":
                plan.outputs += named
        plan.outputs += outputs
        plan.inputs += inputs
        return plan

    def _input_files(self) -> list[_Resolved]:
        out = []
        for named in self.inputs:
            out.append(_Resolved.of(named))
            if named.path.is_dir():
                out += [_Resolved.of(Named(named.option, named.path,
                                           f"its file {p.relative_to(named.path)}"), p)
                        for p in _folder_files(named.path)]
        return out

    def check(self) -> None:
        """Refuse colliding or unwritable outputs (one line); call before any work.

        Raises:
            InputError: naming the option, the path and the fix.
        """
        inputs = _Index(self._input_files())
        seen = _Index([])
        for o in (_Resolved.of(x) for x in self.outputs if not _special(x.path)):
            if (i := inputs.find(o)) is not None:
                raise InputError(f"{o.named}: is the input {i.named}{o.how(i)}; writing it "
                                 f"would replace that input: give {o.named.option} another path")
            if (p := seen.find(o)) is not None:
                raise InputError(f"{o.named}: is also {p.named}{o.how(p)}; one file cannot "
                                 "hold both: give each output its own path")
            for a, b in ((o, seen.around(o)), (seen.inside(o), o)):
                if a is not None and b is not None:
                    raise InputError(f"{a.named}: would be written inside {b.named}, a file "
                                     "this run writes: give them paths that do not overlap")
            seen.add(o)
        check_writable(*dict.fromkeys(o.path for o in self.outputs))


class _Index:
    """Resolved paths found by real path, by inode, and by the folders that hold them."""

    def __init__(self, items: Sequence[_Resolved]) -> None:
        self.real: dict[str, _Resolved] = {}
        self.inode: dict[tuple[int, int], _Resolved] = {}
        self.under: dict[str, _Resolved] = {}  # every folder above an item: the item
        for item in items:
            self.add(item)

    def add(self, item: _Resolved) -> None:
        self.real.setdefault(item.real, item)
        if item.inode is not None:
            self.inode.setdefault(item.inode, item)
        for folder in Path(item.real).parents:
            self.under.setdefault(str(folder), item)

    def find(self, item: _Resolved) -> _Resolved | None:
        """The item that is the same file as ``item``."""
        found = self.real.get(item.real)
        if found is None and item.inode is not None:
            found = self.inode.get(item.inode)
        return found

    def around(self, item: _Resolved) -> _Resolved | None:
        """An item whose path holds ``item`` (a file used as a folder)."""
        return next((self.real[str(f)] for f in Path(item.real).parents
                     if str(f) in self.real), None)

    def inside(self, item: _Resolved) -> _Resolved | None:
        """An item below ``item``'s path."""
        return self.under.get(item.real)


@dataclass(frozen=True)
class Product:
    """One file a command writes: the option that names it, its path, and how to write it
    (atomically, through :mod:`mocap_calib.io.atomic`); ``note`` follows ``wrote PATH`` and
    ``step`` is the progress line before the write, for slow writers."""

    option: str
    path: Path
    write: Callable[[], object]
    note: str = ""
    step: str = ""

    def line(self) -> str:
        return f"wrote {self.path}" + (f"  ({self.note})" if self.note else "")


def write_products(products: Sequence[Product | None],
                   progress: Callable[[str], None] | None = None) -> list[Product]:
    """Write ``products`` (None entries skipped), the first one, the command's result, last;
    returns the products written, the result first (their :meth:`Product.line` is what the
    command prints)."""
    todo = [p for p in products if p is not None]
    for p in [*todo[1:], *todo[:1]]:
        if p.step and progress is not None:
            progress(p.step)
        p.write()
    return todo
