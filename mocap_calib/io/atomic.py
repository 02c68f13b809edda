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
import os
import secrets
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path

from mocap_calib.errors import InputError

#: The temporary files' names: ``.<name>.<pid>.<random>.tmp`` next to the target.
TMP_SUFFIX = ".tmp"
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


def _tmp_name(target: Path) -> Path:
    return target.with_name(f".{target.name}.{os.getpid()}.{secrets.token_hex(4)}{TMP_SUFFIX}")


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
    tmp = _tmp_name(target)
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
        tmp.unlink(missing_ok=True)
    return path


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see the module doc); returns ``path``."""
    return write_with(path, lambda tmp: _write_new(tmp, data))


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8, newlines as given) to ``path`` atomically; returns ``path``."""
    return write_bytes(path, text.encode("utf-8"))


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
        probe = _tmp_name(folder / target.name)
        try:
            _write_new(probe, b"")
        except OSError as err:
            raise write_error(path, err) from None
        finally:
            probe.unlink(missing_ok=True)
        st = os.statvfs(folder)
        free = st.f_bfree if os.geteuid() == 0 else st.f_bavail
        if st.f_blocks > 0 and free == 0:  # (pseudo file systems report no blocks at all)
            raise write_error(path, OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)))


def remove_leftovers(folder: Path) -> None:
    """Temporary files of a run that was killed while writing into ``folder``."""
    if folder.is_dir():
        for tmp in folder.glob(f".*{TMP_SUFFIX}"):
            tmp.unlink(missing_ok=True)
