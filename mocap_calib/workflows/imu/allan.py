"""``mocap-calib allan``: read a long static IMU log, fit its Allan-deviation noise model, write
the noise YAML (Kalibr ``imu.yaml`` keys) and optionally a rerun recording of the curves."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mocap_calib.core.intrinsics.allan import characterise_noise, segments_of, uniform
from mocap_calib.core.intrinsics.noise_result import AllanResult
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.core.params import group, param
from mocap_calib.io.atomic import write_with
from mocap_calib.io.yaml_io import save_yaml
from mocap_calib.report.intrinsics_text import allan_summary
from mocap_calib.workflows.calibrate import HTML_HELP
from mocap_calib.workflows.imu.imu_input import CropSpec, ImuSpec, ProgressFn, say
from mocap_calib.workflows.outputs import OutputPlan, Product, output, write_products
from mocap_calib.workflows.report_files.provenance import RunClock

_HEADER = ("mocap-calib allan noise model (Kalibr imu.yaml keys, SI units). See "
           "docs/conventions.md.")


@dataclass
class AllanRun:
    """A noise characterisation and what it was computed from.

    Attributes:
        result: the noise model per axis and the Allan curves.
        imu: the static log.
        notes: one-line notes (inputs).
        written: files written (the YAML, then the HTML report and the recording).
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


@dataclass
class AllanRequest:
    """Everything ``allan`` can be told."""

    imu: ImuSpec = group(ImuSpec, "Input")
    crop: CropSpec = group(CropSpec, "Input")
    out: Path = output(Path("noise.yaml"), "noise YAML to write", metavar="PATH")
    rrd: Path | None = output(None, "also write a rerun recording of the Allan deviation "
                              "curves and fitted lines (log-log; x: 1000 log10(tau/s))",
                              metavar="PATH", show_default=False)
    aggregate: str = param("mean", "how the Kalibr keys combine the three axes: mean or max "
                           "(conservative)", choices=("mean", "max"))
    tau_min: float | None = param(
        None, "shortest averaging time fitted (raise it when the IMU's low-pass filter bends "
        "the curve at short tau)", unit="s", lo=0.0, lo_open=True, show_default=False)
    allow_unresolved: bool = param(
        False, "write the result even if the log is too short to resolve the random walks "
        "(written as null; calibrate then keeps its defaults for them)",
        decls=("--allow-unresolved",))
    html: Path | None = output(None, HTML_HELP, metavar="PATH", show_default=False)
    quiet: bool = param(False, "no progress lines", decls=("--quiet", "-q"))

    def plan(self) -> OutputPlan:
        return OutputPlan.of(self)


def run_allan(request: AllanRequest, progress: ProgressFn | None = None) -> AllanRun:
    """Read a long static IMU log, fit its Allan-deviation noise model and write it (the
    request's outputs that are not None).

    Raises:
        InputError: bad input files, timestamps or options.
        ObservabilityError: the log is too short, moves, or does not resolve the random walk.
    """
    spec, out, rrd, html = request.imu, request.out, request.rrd, request.html
    clock = RunClock()
    request.plan().check()
    say(progress, f"reading {spec.name}")
    imu, notes = spec.load(request.crop)
    for n in notes:
        say(progress, n)
    if uniform(imu, imu.rate_hz)[1]:
        notes.append("the stamps jitter: each gap-free stretch is resampled to a uniform grid "
                     f"at {imu.rate_hz:.4g} Hz (linear interpolation)")
        say(progress, notes[-1])
    segs = segments_of(imu.t)
    if len(segs) > 1:
        gaps = len(segs) - 1
        notes.append(f"{gaps} gaps in the log ({float(np.diff(imu.t).max()):.3f} s the longest): "
                     f"Allan deviations over its {len(segs)} gap-free stretches combined")
        say(progress, notes[-1])
    say(progress, "computing overlapping Allan deviations and fitting N, B, K per axis")
    result = characterise_noise(imu, aggregate=request.aggregate,  # type: ignore[arg-type]
                                tau_min_s=request.tau_min,
                                require_random_walk=not request.allow_unresolved,
                                unresolved_fix="pass --allow-unresolved")
    run = AllanRun(result, imu, notes)

    def page() -> None:
        from mocap_calib.workflows.report_files.intrinsics import write_allan_html

        write_allan_html(html, result, [spec.imu], clock)

    def recording() -> None:
        from mocap_calib.viz.allan_plot import write_allan_recording

        write_with(rrd, lambda tmp: write_allan_recording(tmp, result))

    written = write_products([
        None if out is None else Product("--out", out,
                                         lambda: save_yaml(out, run.to_dict(), _HEADER)),
        None if html is None else Product("--html", html, page, step="writing HTML report"),
        None if rrd is None else Product("--rrd", rrd, recording, step="writing rerun recording"),
    ], progress)
    run.written = [p.path for p in written]
    return run
