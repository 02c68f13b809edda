"""``mocap-calib export``: a calibration result as another tool's configuration file."""

from __future__ import annotations

from dataclasses import MISSING, dataclass
from pathlib import Path

from mocap_calib.core.params import param
from mocap_calib.errors import InputError
from mocap_calib.export.imu_tk import SUFFIXES
from mocap_calib.export.targets import (
    FILE_NAMES,
    TARGETS,
    Exported,
    ExportInputs,
    export_calibration,
)
from mocap_calib.io.yaml_io import check_writable, load_result, save_text
from mocap_calib.workflows.imu.intrinsics_export import INTRINSICS_FORMATS, export_intrinsics
from mocap_calib.workflows.outputs import Named, OutputPlan, output
from mocap_calib.workflows.session import NoiseSpec

__all__ = ["TARGETS", "FILE_NAMES", "export_to_file", "export_result", "ALL_TARGETS"]

#: Every ``--to``: the calibration targets and the intrinsics ones (multipos -> imu_tk).
ALL_TARGETS = (*TARGETS, *INTRINSICS_FORMATS)
TARGETS_HELP = ", ".join(f"{t} ({FILE_NAMES[t]})" for t in TARGETS) + (
    "; imu_tk (multipos intrinsics: OUT_acc.calib and OUT_gyro.calib, T K (raw - b))")


@dataclass
class ExportRequest:
    """Everything ``export`` can be told."""

    calibration: Path = param(
        MISSING, "result YAML of 'mocap-calib calibrate' (for --to imu_tk: intrinsics of "
        "'mocap-calib multipos')", argument=True, metavar="CALIBRATION")
    to: str = param(MISSING, "target tool", choices=ALL_TARGETS, decls=("--to",))
    out: Path | None = output(
        None, "file to write (default: the tool's own file name); imu_tk: the prefix of its "
        "two files (default 'imu')", kind="prefix", metavar="PATH", show_default=False)
    noise: Path | None = param(
        None, "noise YAML (Kalibr keys, e.g. from 'mocap-calib allan'); default: the noise "
        "model the calibration used", metavar="PATH", show_default=False)
    imu_rate: float | None = param(None, "IMU rate (default: the one measured by the "
                                   "calibration)", unit="Hz", lo=0.0, lo_open=True,
                                   show_default=False)
    imu_topic: str = param("/imu0", "IMU topic for the targets that name it")

    def plan(self) -> OutputPlan:
        """The tool's file (``--out``, or its own name), or imu_tk's two files."""
        if self.to in INTRINSICS_FORMATS:
            prefix = self.out or Path("imu")
            files = [Named("--out", Path(f"{prefix}{s}")) for s in SUFFIXES.values()]
        else:
            files = [Named("--out", self.out or Path(FILE_NAMES.get(self.to, "export")))]
        return OutputPlan.of(self, outputs=files)


def export_request(request: ExportRequest) -> list[str]:
    """``export`` from its request (see :func:`export_result`)."""
    r = request
    r.plan().check()
    return export_result(r.calibration, r.to, r.out, r.noise, r.imu_rate, r.imu_topic)


def export_result(path: Path, target: str, out: Path | None = None, noise: Path | None = None,
                  imu_rate_hz: float | None = None, imu_topic: str = "/imu0") -> list[str]:
    """``mocap-calib export``: a calibration (or, for imu_tk, multipos intrinsics) in
    ``target``'s format; returns the lines to print."""
    if target in INTRINSICS_FORMATS:
        return export_intrinsics(path, target, out or Path("imu")).summary().splitlines()
    if target not in TARGETS:
        raise InputError(f"unknown --to '{target}'; choose one of: {', '.join(ALL_TARGETS)}")
    exported, written = export_to_file(path, target, out, noise, imu_rate_hz, imu_topic)
    return [f"note: {n}" for n in exported.notes] + [f"wrote {written}  ({target})"]


def export_to_file(calibration: Path, target: str, out: Path | None = None,
                   noise: Path | None = None, imu_rate_hz: float | None = None,
                   imu_topic: str = "/imu0") -> tuple[Exported, Path]:
    """Read ``calibration`` (and ``noise``), build the ``target`` file and write it.

    Args:
        calibration: a result of ``mocap-calib calibrate`` (or a simulator truth file).
        target: one of :data:`TARGETS`.
        out: file to write (default: the tool's own file name, in the current folder).
        noise: noise YAML (Kalibr keys, e.g. from ``mocap-calib allan``); default: the noise
            model the calibration used.
        imu_rate_hz: IMU rate; default: the one the calibration measured.
        imu_topic: IMU topic for the targets that name it.

    Returns:
        What was exported and the path written.
    """
    if target not in TARGETS:
        raise InputError(f"unknown --to '{target}'; choose one of: {', '.join(TARGETS)}")
    out = Path(out) if out is not None else Path(FILE_NAMES[target])
    check_writable(out)
    result = load_result(calibration)
    if noise is not None:
        noise_model, source = NoiseSpec(noise=Path(noise)).resolve(None), f"from {noise}"
    else:
        noise_model = result.noise
        source = f"the noise model of {calibration} (give --noise noise.yaml from 'allan')"
    rate = imu_rate_hz or result.session.get("imu_rate_hz")
    if rate is None:
        raise InputError(f"{calibration}: the IMU rate is not in the file; pass --imu-rate HZ")
    if not float(rate) > 0:
        raise InputError(f"--imu-rate {rate}: must be positive")
    inputs = ExportInputs(result, noise_model, source, float(rate), imu_topic, str(calibration))
    exported = export_calibration(inputs, target)
    if noise is None:
        exported.notes.append(f"noise densities are those {calibration} was calibrated with; "
                              "measure yours with 'mocap-calib allan' and pass --noise")
    return exported, save_text(out, exported.text)
