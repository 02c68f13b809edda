"""The one way mocap-calib writes a file: whole or not at all, and a failure is one line.

A file is written under a temporary name in its own folder, flushed and fsync'ed, then renamed
over the target (and the folder fsync'ed): a reader, a full disk, a kill or Ctrl-C leaves the
old file or the new one, never a truncated one where a good one was. A write that fails (a full
disk, a read-only folder, a path through a file) raises one :class:`InputError` line naming
the file and the problem, and leaves nothing behind.

A target that is not a regular file (``/dev/null``, ``/dev/stdout``, a pipe, ``/dev/full``)
cannot be renamed over (that would replace the device node itself): the content is prepared
in a temporary file elsewhere and copied into it, and the device's own error (``/dev/full``:
no space left) is the one line. :func:`check_writable` checks outputs before a long run.
"""

from __future__ import annotations

import errno
import hashlib
import os
import re
import secrets
import socket
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path

from mocap_calib.errors import InputError

#: The temporary files' names, next to the target: ``.<name>.mocap-calib-<host>-<pid>-<random>
#: .tmp`` (``host``: 6 hex digits of this machine's name, so that a folder shared between
#: machines is swept only of this machine's files). Nothing else is ever removed as a leftover.
TMP_SUFFIX = ".tmp"
TMP_TAG = "mocap-calib"
_HOST = hashlib.sha1(socket.gethostname().encode("utf-8", "surrogateescape")).hexdigest()[:6]
_TMP_NAME = re.compile(rf"^\..+\.{TMP_TAG}-(?P<host>[0-9a-f]{{6}})-(?P<pid>[0-9]+)-[0-9a-f]{{8}}"
                       rf"{re.escape(TMP_SUFFIX)}$", re.DOTALL)
#: How much of the target's name a temporary name keeps (file names are at most 255 bytes).
_NAME_KEPT = 120
_COPY_CHUNK = 1 << 20


def write_error(path: str | Path, err: OSError) -> InputError:
    """The one line for a failed write of ``path``."""
    why = err.strerror or str(err)
    if err.errno in (errno.ENOSPC, errno.EDQUOT):
        fix = "free some space or choose another output path"
    elif err.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
        fix = "choose a folder you can write to"
    elif err.errno in (errno.ENOTDIR, errno.ENOENT):
        fix = "check the folders in the output path"
    else:
        fix = "choose another output path"
    return InputError(f"{path}: cannot write ({why}); {fix}")


#: Paths that name an open stream (``/dev/stdout``, ``/dev/fd/3``, ``/proc/self/fd/1``): written
#: into even when the stream is a regular file (``> log.txt``), which a rename would replace.
_STREAM_FOLDERS = ("/dev/", "/proc/")


def _special(target: Path) -> bool:
    """An existing target that is not a regular file or folder (device, pipe, socket), or a
    stream's name (see :data:`_STREAM_FOLDERS`)."""
    try:
        mode = target.stat().st_mode
    except OSError:
        return False
    if stat.S_ISDIR(mode):
        return False
    return not stat.S_ISREG(mode) or os.path.abspath(target).startswith(_STREAM_FOLDERS)


def temporary_name(target: Path, pid: int | None = None) -> Path:
    """The temporary file for ``target`` of process ``pid`` (default: this one)."""
    pid = os.getpid() if pid is None else pid
    return target.with_name(f".{target.name[:_NAME_KEPT]}.{TMP_TAG}-{_HOST}-{pid}-"
                            f"{secrets.token_hex(4)}{TMP_SUFFIX}")


def _discard(path: Path) -> None:
    """Remove a temporary file if it is there. A read-only file system refuses even the removal
    of a file that does not exist (EROFS, not ENOENT); a cleanup never adds an error of its own
    to the one being reported."""
    try:
        os.unlink(path)
    except OSError:
        pass


def _fsync(path: Path, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    except OSError as err:
        if err.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):  # not fsync-able
            raise
    finally:
        os.close(fd)


def _write_new(path: Path, data: bytes) -> None:
    """Create ``path`` (which must not exist) with ``data``, flushed to the disk."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # the umask applies
    with os.fdopen(fd, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def _copy_into(source: Path, target: Path) -> None:
    """Copy into an existing special file (a device or pipe), with its errors."""
    with source.open("rb") as src, target.open("wb") as dst:
        while chunk := src.read(_COPY_CHUNK):
            dst.write(chunk)
        dst.flush()
        try:
            os.fsync(dst.fileno())
        except OSError as err:
            if err.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):
                raise


def write_with(path: str | Path, write: Callable[[Path], object]) -> Path:
    """Write ``path`` atomically with ``write(tmp)``, which creates the file ``tmp`` (for
    writers that take a path, such as rerun's); returns ``path``.

    Raises:
        InputError: the file cannot be written (one line naming it and the problem).
    """
    path = Path(path)
    if _special(path):  # (through links: /dev/stdout is one to a pipe, not to a path)
        with tempfile.TemporaryDirectory(prefix="mocap-calib-") as folder:
            tmp = Path(folder) / path.name
            write(tmp)
            try:
                _copy_into(tmp, path)
            except OSError as err:
                raise write_error(path, err) from None
        return path
    target = Path(os.path.realpath(path))  # through symlinks: the link stays a link
    tmp = temporary_name(target)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        write(tmp)
        if not tmp.is_file():
            raise OSError(errno.EIO, "the writer produced no file")
        _fsync(tmp)
        if target.is_file():  # keep the permissions of the file replaced
            os.chmod(tmp, stat.S_IMODE(target.stat().st_mode))
        os.replace(tmp, target)
        _fsync(target.parent, directory=True)
    except OSError as err:
        raise write_error(path, err) from None
    finally:
        _discard(tmp)
    return path


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see the module doc); returns ``path``."""
    return write_with(path, lambda tmp: _write_new(tmp, data))


#: Bytes of a file name that are not UTF-8 reach Python as lone surrogates U+DC80-U+DCFF.
_UNDECODED = re.compile("[\udc80-\udcff]")


def printable(text: str) -> str:
    """``text`` with the bytes of a file name that were not UTF-8 shown as ``\\xNN`` (as
    ``ls -b`` shows them), so that it can be written as UTF-8; other text is unchanged."""
    text = _UNDECODED.sub(lambda m: f"\\x{ord(m.group()) - 0xDC00:02x}", text)
    return text.encode("utf-8", "backslashreplace").decode("utf-8")


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8, newlines as given) to ``path`` atomically; returns ``path``.
    File names with bytes that are not UTF-8 appear as ``\\xNN`` (:func:`printable`)."""
    return write_bytes(path, printable(text).encode("utf-8"))


def _existing_ancestor(folder: Path) -> Path:
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    return folder


def check_writable(*paths: str | Path | None) -> None:
    """Before a long computation: each output can be written (``None`` entries are skipped).

    A regular file's folder (or the nearest folder that exists, where the missing ones will be
    created) must take a new file, checked by creating and removing one, on a disk that is not
    full; a device or pipe must be open for writing (its own errors, such as ``/dev/full``'s,
    come when it is written).

    Raises:
        InputError: one line naming the output and the problem.
    """
    for p in paths:
        if p is None:
            continue
        path = Path(p)
        if path.is_dir():
            raise InputError(f"{path}: is a folder; give a file name")
        if _special(path):
            if not os.access(path, os.W_OK):
                raise InputError(f"{path}: cannot write (permission denied); choose another "
                                 "output path")
            continue
        target = Path(os.path.realpath(path))
        folder = _existing_ancestor(target.parent if str(target.parent) else Path("."))
        if not folder.is_dir():
            raise InputError(f"{path}: {folder} is a file, not a folder; choose another output "
                             "path")
        probe = temporary_name(folder / target.name)
        try:
            _write_new(probe, b"")
        except OSError as err:
            raise write_error(path, err) from None
        finally:
            _discard(probe)
        st = os.statvfs(folder)
        free = st.f_bfree if os.geteuid() == 0 else st.f_bavail
        if st.f_blocks > 0 and free == 0:  # (pseudo file systems report no blocks at all)
            raise write_error(path, OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)))


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return pid > 0  # another user's process (or a pid this system cannot have)
    return True


def leftover(name: str) -> bool:
    """Whether ``name`` is a temporary file of a mocap-calib process of this machine that is
    gone, or of this process (a write it did not finish)."""
    m = _TMP_NAME.match(name)
    if m is None or m["host"] != _HOST:
        return False
    pid = int(m["pid"])
    return pid == os.getpid() or not _alive(pid)


def remove_leftovers(folder: Path, within: Path | None = None) -> list[Path]:
    """Remove the temporary files a killed run left directly in ``folder``: only names of
    mocap-calib's pattern (:func:`leftover`), only regular files (never through a symbolic
    link), and nothing when ``folder`` is itself a link or lies, through links, outside
    ``within``. Returns what was removed."""
    folder = Path(folder)
    if folder.is_symlink() or not folder.is_dir():
        return []
    if within is not None:
        real, root = os.path.realpath(folder), os.path.realpath(within)
        if real != root and not real.startswith(root.rstrip(os.sep) + os.sep):
            return []
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return []
    for entry in entries:
        if leftover(entry.name) and entry.is_file(follow_symlinks=False):
            _discard(Path(entry.path))
            removed.append(Path(entry.path))
    return removed
