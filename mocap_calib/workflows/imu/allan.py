"""``mocap-calib allan``: read a long static IMU log, fit its Allan-deviation noise model, write
the noise YAML (Kalibr ``imu.yaml`` keys) and optionally a rerun recording of the curves."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mocap_calib.core.intrinsics.allan import characterise_noise
from mocap_calib.core.intrinsics.noise_result import AllanResult
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.errors import InputError
from mocap_calib.io.atomic import write_with
from mocap_calib.io.yaml_io import check_writable, save_yaml
from mocap_calib.report.intrinsics_text import allan_summary
from mocap_calib.workflows.html.provenance import RunClock
from mocap_calib.workflows.imu.imu_input import ImuSpec, ProgressFn, say

_HEADER = ("mocap-calib allan noise model (Kalibr imu.yaml keys, SI units). See "
           "docs/conventions.md.")


@dataclass
class AllanRun:
    """A noise characterisation and what it was computed from.

    Attributes:
        result: the noise model per axis and the Allan curves.
        imu: the static log.
        notes: one-line notes (inputs).
        written: files written (the HTML report, the YAML, then the recording).
    """

    result: AllanResult
    imu: ImuSamples
    notes: list[str] = field(default_factory=list)
    written: list[Path] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """``kind``/``version`` and the Kalibr ``imu.yaml`` keys first (as
        :meth:`AllanResult.to_dict`), then the inputs."""
        d = self.result.to_dict()
        d["inputs"] = list(self.notes)
        return d

    def summary(self) -> str:
        return allan_summary(self.result)


def run_allan(spec: ImuSpec, *, out: Path | None = None, rrd: Path | None = None,
              aggregate: str = "mean", tau_min_s: float | None = None,
              require_random_walk: bool = True, progress: ProgressFn | None = None,
              html: Path | None = None) -> AllanRun:
    """Read a long static IMU log, fit its Allan-deviation noise model and write it.

    Args:
        spec: the IMU log.
        out: noise YAML to write (None: write nothing).
        rrd: rerun recording of the curves to write (None: none).
        aggregate: ``mean`` or ``max`` over the axes for the Kalibr keys.
        tau_min_s: shortest averaging time fitted (s); None: one sample.
        require_random_walk: fail when the log does not resolve the random walks (otherwise
            they are written as null).
        progress: one-line progress callback.
        html: self-contained HTML report to write (None: none).

    Raises:
        InputError: bad input files, timestamps or options.
        ObservabilityError: the log is too short, moves, or does not resolve the random walk.
    """
    if aggregate not in ("mean", "max"):
        raise InputError(f"--aggregate {aggregate}: use mean or max")
    if tau_min_s is not None and not (np.isfinite(tau_min_s) and tau_min_s > 0):
        raise InputError(f"--tau-min {tau_min_s}: must be a positive time in s")
    clock = RunClock()
    check_writable(out, rrd, html)
    say(progress, f"reading {spec.name}")
    imu, notes = spec.load()
    for n in notes:
        say(progress, n)
    say(progress, "computing overlapping Allan deviations and fitting N, B, K per axis")
    result = characterise_noise(imu, aggregate=aggregate,  # type: ignore[arg-type]
                                tau_min_s=tau_min_s, require_random_walk=require_random_walk,
                                unresolved_fix="pass --allow-unresolved")
    run = AllanRun(result, imu, notes)
    if html is not None:
        from mocap_calib.workflows.html.intrinsics import write_allan_html

        say(progress, "writing HTML report")
        run.written.append(write_allan_html(html, result, [spec.imu], clock))
    if out is not None:
        run.written.append(save_yaml(out, run.to_dict(), _HEADER))
    if rrd is not None:
        from mocap_calib.viz.allan_plot import write_allan_recording

        say(progress, "writing rerun recording")
        run.written.append(write_with(rrd, lambda tmp: write_allan_recording(tmp, result)))
    return run
