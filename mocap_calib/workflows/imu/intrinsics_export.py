"""``mocap-calib export INTRINSICS --to imu_tk``: multipos intrinsics in imu_tk's calibration
files."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from mocap_calib.errors import InputError
from mocap_calib.export.imu_tk import SUFFIXES, write_imu_tk
from mocap_calib.io.result_files import read_intrinsics
from mocap_calib.io.yaml_io import check_writable

#: Formats multipos intrinsics can be exported to.
INTRINSICS_FORMATS = ("imu_tk",)


@dataclass
class ExportRun:
    """What an export wrote.

    Attributes:
        written: the files.
        notes: one-line notes (what the format leaves out).
    """

    written: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def summary(self) -> str:
        return "\n".join([f"wrote {p}" for p in self.written] + [f"note: {n}"
                                                                 for n in self.notes])


def export_intrinsics(path: Path, to: str, out: Path) -> ExportRun:
    """Write multipos intrinsics in another tool's format.

    Args:
        path: intrinsics YAML written by ``mocap-calib multipos``.
        to: the format (``imu_tk``: ``OUT_acc.calib`` and ``OUT_gyro.calib``).
        out: output prefix.

    Raises:
        InputError: unknown format, not an intrinsics file, unwritable output.
    """
    if to not in INTRINSICS_FORMATS:
        raise InputError(f"--to {to}: multipos intrinsics export to "
                         f"{', '.join(INTRINSICS_FORMATS)}")
    check_writable(*(Path(f"{out}{s}") for s in SUFFIXES.values()))
    result = read_intrinsics(path)
    run = ExportRun(write_imu_tk(out, result, str(path)))
    units = "raw counts" if result.raw_input is not None else "the SI readings"
    run.notes.append(f"calibrated = T K (raw - b) in m/s^2 and rad/s, raw = {units}")
    if result.g_sensitivity is not None:
        run.notes.append("the gyro's g-sensitivity G is not in imu_tk's format: imu_tk's "
                         "calibrated rate keeps G f")
    return run
