"""``view``: open a rerun recording in the rerun viewer, or say how to open it elsewhere."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import MISSING, dataclass
from pathlib import Path

from mocap_calib.core.params import param
from mocap_calib.errors import CalibrationError, InputError

#: First bytes of an ``.rrd`` file (rerun's stream header).
RRD_MAGIC = b"RRF"


def check_recording(path: Path) -> Path:
    """Check that ``path`` is a readable rerun recording.

    Raises:
        InputError: the file is missing, a folder, or not a rerun recording.
    """
    if not path.exists():
        raise InputError(f"{path}: file not found; write a recording with "
                         "'mocap-calib calibrate ... --rrd FILE.rrd'")
    if not path.is_file():
        raise InputError(f"{path}: is a folder; give a .rrd file written by 'calibrate --rrd'")
    try:
        with path.open("rb") as fh:
            head = fh.read(len(RRD_MAGIC))
    except OSError as err:
        raise InputError(f"{path}: cannot be read ({err.strerror})") from None
    if head != RRD_MAGIC:
        raise InputError(f"{path}: not a rerun recording (.rrd); open a file written by "
                         "'mocap-calib calibrate --rrd'")
    return path


def viewer_executable() -> str | None:
    """The ``rerun`` executable of rerun-sdk: on PATH or next to this Python."""
    found = shutil.which("rerun")
    if found:
        return found
    local = Path(sys.executable).parent / ("rerun.exe" if os.name == "nt" else "rerun")
    return str(local) if local.is_file() else None


def has_display() -> bool:
    """Whether a native window can be opened (on Linux: an X11 or Wayland display)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


@dataclass
class ViewRequest:
    """What ``view`` opens."""

    recording: Path = param(MISSING, "the .rrd file to open", argument=True, metavar="RECORDING")


def open_recording(recording: Path) -> str | None:
    """Start the viewer on ``recording``; without a viewer or display return what to do."""
    path = check_recording(recording)
    exe = viewer_executable()
    if exe is None or not has_display():
        why = ("no display here for the rerun viewer" if exe is not None
               else "the rerun viewer is not installed here")
        return (f"{why}; open the recording with 'rerun {path}' on a machine with a display "
                "(pip install 'rerun-sdk==0.41.*'), or in a browser with "
                f"'rerun --web-viewer {path}' and http://localhost:9090")
    try:
        code = subprocess.call([exe, str(path)])
    except OSError as err:
        raise CalibrationError(f"cannot start the rerun viewer {exe} ({err.strerror}); run "
                               f"'rerun {path}' yourself") from None
    if code != 0:
        raise CalibrationError(f"the rerun viewer exited with code {code}; try "
                               f"'rerun --web-viewer {path}' and open http://localhost:9090")
    return None
