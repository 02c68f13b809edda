"""No data loss reported as success: every output goes through one atomic writer
(``mocap_calib/io/atomic.py``); a write that fails ends with one line naming the file and the
problem and a non-zero exit, and never leaves a truncated file where a good one was.

Disk full is ``/dev/full`` (a device: written into, never renamed over) and a file-size limit
(RLIMIT_FSIZE: every write past it fails, as on a full disk); a read-only folder is one this
user cannot write (``/sys`` when running as root, who may write anywhere else).
"""

from __future__ import annotations

import os
import resource
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from mocap_calib.cli.main import main
from mocap_calib.workflows.simulate import simulate_to_folder

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

ENTRY = Path(sys.executable).parent / "mocap-calib"
DEV_FULL = Path("/dev/full")
needs_dev_full = pytest.mark.skipif(not DEV_FULL.exists(), reason="no /dev/full here")


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("writes") / "s"
    simulate_to_folder(out, seed=5, duration=30.0)
    return out


@pytest.fixture(scope="module")
def result(session: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("result") / "calib.yaml"
    assert main(["calibrate", str(session), "--out", str(out), "--segments", "0", "-q"]) == 0
    return out


def _cli(*args: str, limit: int | None = None) -> subprocess.CompletedProcess[str]:
    """The command in a process of its own (with a file-size limit), or in this one."""
    if limit is None:
        import contextlib
        import io

        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(list(args))
        return subprocess.CompletedProcess(list(args), code, out.getvalue(), err.getvalue())

    def set_limit() -> None:  # Python ignores SIGXFSZ: writes past it fail with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return subprocess.run([str(ENTRY), *args], capture_output=True, text=True, timeout=300,
                          preexec_fn=set_limit)


def _one_line(proc: subprocess.CompletedProcess[str], *words: str) -> str:
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("error: "), proc.stderr
    for w in words:
        assert w in last, last
    return last


def _still_a_device() -> None:
    assert stat.S_ISCHR(DEV_FULL.stat().st_mode), "/dev/full was replaced by a file"


def unwritable_folder(tmp_path: Path) -> Path:
    """A folder this user cannot create files in."""
    ro = tmp_path / "read_only"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        (ro / "probe").touch()
    except PermissionError:
        return ro
    (ro / "probe").unlink()  # root writes anywhere: a pseudo file system it cannot
    for folder in (Path("/sys"), Path("/proc")):
        try:
            (folder / "mocap-calib-probe").touch()
        except OSError:
            return folder
    pytest.skip("no folder here that this user cannot write")


@needs_dev_full
@pytest.mark.parametrize("option", ["--out", "--report", "--rrd"])
def test_calibrate_to_a_full_disk_fails_loudly(session: Path, tmp_path: Path,
                                               option: str) -> None:
    """``--out /dev/full`` exited 0 (the temporary file was renamed over the device node):
    now the device is written into and its error is the one line."""
    out = tmp_path / "calib.yaml"
    args = ["--out", str(out)] if option != "--out" else []
    proc = _cli("calibrate", str(session), *args, option, str(DEV_FULL), "--segments", "0")
    _one_line(proc, "/dev/full: cannot write (No space left on device)", "free some space")
    _still_a_device()
    assert not out.exists()  # the result is written last
    assert not list(tmp_path.glob(".*tmp"))


@needs_dev_full
def test_other_commands_to_a_full_disk_fail_loudly(session: Path, result: Path) -> None:
    for args in (["export", str(result), "--to", "kalibr", "--out", str(DEV_FULL)],
                 ["groundtruth", str(session), "--calibration", str(result), "--out",
                  str(DEV_FULL)]):
        _one_line(_cli(*args), "/dev/full: cannot write (No space left on device)")
        _still_a_device()


def test_dev_null_and_stdout_are_outputs(result: Path, capfd: pytest.CaptureFixture[str]
                                         ) -> None:
    """A device that takes the bytes is a fine output (nothing is renamed over it)."""
    assert _cli("export", str(result), "--to", "kalibr", "--out", "/dev/null").returncode == 0
    assert stat.S_ISCHR(Path("/dev/null").stat().st_mode)
    capfd.readouterr()
    assert _cli("export", str(result), "--to", "kalibr", "--out", "/dev/stdout").returncode == 0
    assert "Kalibr IMU configuration" in capfd.readouterr().out  # the file, through fd 1


@pytest.mark.parametrize("option", ["--rrd", "--html"])
def test_a_write_that_fails_midway_keeps_the_old_file(session: Path, tmp_path: Path,
                                                      option: str) -> None:
    """Writes past a file-size limit fail (as on a full disk) in the middle of the file: the
    old file stays whole, no temporary file is left, one line names the file. rerun's own
    writer used to end this with exit 70 (its RuntimeError), or a truncated recording."""
    out, extra = tmp_path / "calib.yaml", tmp_path / f"view{option.replace('--', '.')}"
    extra.write_text("previous\n")
    proc = _cli("calibrate", str(session), "--out", str(out), option, str(extra),
                "--segments", "0", limit=200_000)
    _one_line(proc, f"{extra}: cannot write")
    assert extra.read_text() == "previous\n"
    assert not out.exists()
    assert not list(tmp_path.glob(".*tmp"))


def test_read_only_folder_is_refused_before_the_run(session: Path, tmp_path: Path) -> None:
    ro = unwritable_folder(tmp_path)
    for target in (ro / "calib.yaml", ro / "new_folder" / "calib.yaml"):
        proc = _cli("calibrate", str(session), "--out", str(target))
        _one_line(proc, f"{target}: cannot write")
        assert "stage" not in proc.stderr, "refused only after calibrating"


def test_a_folder_that_is_a_file_is_refused_before_the_run(session: Path,
                                                           tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("a file\n")
    target = tmp_path / "notes.txt" / "calib.yaml"
    proc = _cli("calibrate", str(session), "--out", str(target))
    _one_line(proc, str(target), "notes.txt is a file, not a folder")
    assert "stage" not in proc.stderr, "refused only after calibrating"


def test_simulate_and_batch_into_a_read_only_folder(session: Path, tmp_path: Path) -> None:
    ro = unwritable_folder(tmp_path)
    _one_line(_cli("simulate", str(ro / "sim"), "--duration", "20"), "cannot write")
    manifest = tmp_path / "manifest.yaml"
    manifest.write_text(f"sessions:\n  - id: one\n    imu_id: a\n    date: 2024-01-01\n"
                        f"    mav0: {session}\n")
    _one_line(_cli("batch", str(manifest), "--out", str(ro / "batch"), "--quiet"),
              "cannot write")


def test_a_missing_output_folder_is_created(result: Path, tmp_path: Path) -> None:
    target = tmp_path / "new" / "deeper" / "kalibr.yaml"
    assert _cli("export", str(result), "--to", "kalibr", "--out", str(target)).returncode == 0
    assert target.is_file()


def test_a_symlinked_output_stays_a_link(result: Path, tmp_path: Path) -> None:
    real = tmp_path / "real.yaml"
    real.write_text("old\n")
    link = tmp_path / "link.yaml"
    link.symlink_to(real)
    os.chmod(real, 0o640)
    assert _cli("export", str(result), "--to", "kalibr", "--out", str(link)).returncode == 0
    assert link.is_symlink() and real.read_text() != "old\n"
    assert stat.S_IMODE(real.stat().st_mode) == 0o640  # the replaced file's permissions


def test_a_full_disk_is_refused_before_the_run(session: Path, tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """The folder's file system reports no free block: refused before calibrating."""
    import collections

    from mocap_calib.io import atomic

    full = collections.namedtuple("full", "f_blocks f_bfree f_bavail")(1000, 0, 0)
    monkeypatch.setattr(atomic.os, "statvfs", lambda _path: full)
    proc = _cli("calibrate", str(session), "--out", str(tmp_path / "calib.yaml"))
    _one_line(proc, "calib.yaml: cannot write (No space left on device)", "free some space")
    assert "stage" not in proc.stderr
