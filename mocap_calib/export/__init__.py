"""Exports of a calibration to the configuration files of other tools.

Each target writes what that tool reads, in that tool's frames and time-offset sign; the
conventions are in ``docs/exports.md`` and :mod:`mocap_calib.export.targets`. Multipos
intrinsics go to imu_tk's calibration files (:mod:`mocap_calib.export.imu_tk`). This layer may
use ``core`` (the result, the noise model) and ``io``; it returns text, the workflow writes it.
"""

from mocap_calib.export.targets import TARGETS, Exported, ExportInputs, export_calibration

__all__ = ["TARGETS", "ExportInputs", "Exported", "export_calibration"]
