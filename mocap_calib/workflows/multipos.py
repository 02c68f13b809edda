"""``mocap-calib multipos``: read an IMU log (and earlier intrinsics as a prior), calibrate its
intrinsics from a multi-position session, write the intrinsics YAML."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from mocap_calib.core.intrinsics.multipos import (
    PARAMETERS,
    MultiposPrior,
    MultiposResult,
    calibrate_multipos,
)
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.errors import InputError
from mocap_calib.io.result_files import INTRINSICS_FIX, read_intrinsics
from mocap_calib.io.yaml_io import check_writable, save_yaml
from mocap_calib.report.intrinsics_text import multipos_summary
from mocap_calib.workflows.imu_input import ImuSpec, ProgressFn, say

#: Parameters a multipos prior constrains by default: the matrices. Turn-on biases change from
#: one power-up to the next by more than a session's sigma, so they are opt-in.
PRIOR_DEFAULT_NAMES: tuple[str, ...] = ("accel_matrix", "gyro_matrix")

#: How the core's messages name the options: as the command line spells them.
CLI_NAMES = {"init_static_s": "--init-static", "window_s": "--window",
             "min_interval_s": "--min-interval", "min_orientations": "--min-orientations",
             "gravity": "--gravity"}

_HEADER = ("mocap-calib multipos intrinsics (SI units; 1-sigma under 'sigma').\n"
           "a_m = M_a f + b_a (accel_matrix lower-triangular), w_m = M_g w + b_g. "
           "See docs/conventions.md.")


def load_multipos_prior(paths: Sequence[Path], at_time_s: float, *,
                        include_biases: bool = False, sigma_scale: float = 1.0
                        ) -> MultiposPrior:
    """Prior from earlier multipos intrinsics: one file as is, two or more as a trend.

    Args:
        paths: earlier intrinsics YAMLs written by ``mocap-calib multipos``.
        at_time_s: the new session's time (s since the Unix epoch of the stamps) to extrapolate
            the first-order trend to (used with two or more files).
        include_biases: constrain ``accel_bias`` and ``gyro_bias`` too (default: only the
            matrices, which are stable; turn-on biases are not).
        sigma_scale: multiply the prior's sigmas by this (> 1 allows for change since then).

    Raises:
        InputError: a file is not multipos intrinsics, or has no session time for a trend.
    """
    if not (np.isfinite(sigma_scale) and sigma_scale > 0):
        raise InputError(f"--prior-sigma-scale must be positive, got {sigma_scale}")
    results = [read_intrinsics(p) for p in paths]
    names = tuple(PARAMETERS) if include_biases else PRIOR_DEFAULT_NAMES
    files = ", ".join(str(p) for p in paths)
    if len(results) == 1:
        prior = MultiposPrior.from_result(results[0], names=names, sigma_scale=sigma_scale)
    else:
        for p, r in zip(paths, results, strict=True):
            if r.session_time_ns == 0:
                raise InputError(f"{p}: no 'diagnostics: {{session_time_ns: ...}}', needed for "
                                 f"a trend over several priors; {INTRINSICS_FIX}")
        prior = MultiposPrior.from_history(
            results, times_s=[r.session_time_ns * 1e-9 for r in results], at_time_s=at_time_s,
            names=names, sigma_scale=sigma_scale)
    return replace(prior, source=f"{prior.source} ({files}; {', '.join(names)})")


@dataclass
class MultiposRun:
    """A multipos calibration and what it was computed from.

    Attributes:
        result: the intrinsics with 1-sigma, residuals and diagnostics.
        imu: the IMU log.
        notes: one-line notes (inputs, prior).
        written: files written.
    """

    result: MultiposResult
    imu: ImuSamples
    notes: list[str] = field(default_factory=list)
    written: list[Path] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """The intrinsics file: ``kind``/``version``, the conventions' intrinsics keys,
        ``sigma``, ``residuals``, ``diagnostics``, and the inputs."""
        d = self.result.to_dict()
        d["inputs"] = list(self.notes)
        return d

    def summary(self) -> str:
        return multipos_summary(self.result)


def run_multipos(spec: ImuSpec, *, out: Path | None = None, init_static_s: float = 30.0,
                 window_s: float = 1.0, min_interval_s: float = 0.5, gravity: float = 9.81,
                 min_orientations: int = 9, prior_files: Sequence[Path] = (),
                 prior_biases: bool = False, prior_sigma_scale: float = 1.0,
                 progress: ProgressFn | None = None) -> MultiposRun:
    """Read an IMU log, calibrate its intrinsics from a multi-position session, and write them.

    Args:
        spec: the IMU log.
        out: intrinsics YAML to write (None: write nothing).
        init_static_s: length of the initial rest period, s.
        window_s: static-detector window, s.
        min_interval_s: shortest static interval used, s.
        gravity: local ``|g|``, m/s^2.
        min_orientations: fewest distinct static orientations accepted.
        prior_files: earlier intrinsics (one: a prior; two or more: a first-order trend
            extrapolated to this session's first stamp).
        prior_biases: let the prior constrain the biases too.
        prior_sigma_scale: widen (> 1) the prior's sigmas.
        progress: one-line progress callback.

    Raises:
        InputError: bad input files or options.
        ObservabilityError: no initial rest, too short, too few orientations.
        ConvergenceError: a fit failed.
    """
    check_writable(out)
    prior_files = list(prior_files)
    # Check the priors before the (longer) IMU read so a wrong file fails fast.
    for p in prior_files:
        read_intrinsics(p)
    say(progress, f"reading {spec.imu}")
    imu, notes = spec.load()
    for n in notes:
        say(progress, n)
    prior = None
    if prior_files:
        prior = load_multipos_prior(prior_files, float(imu.stamps_ns()[0]) * 1e-9,
                                    include_biases=prior_biases, sigma_scale=prior_sigma_scale)
        notes.append(f"prior: {prior.source}")
        say(progress, f"prior: {prior.source}")
    say(progress, "detecting static intervals and fitting accelerometer and gyroscope")
    result = calibrate_multipos(imu, init_static_s=init_static_s, window_s=window_s,
                                min_interval_s=min_interval_s, gravity=gravity,
                                min_orientations=min_orientations, prior=prior,
                                names=CLI_NAMES)
    run = MultiposRun(result, imu, notes)
    if out is not None:
        run.written.append(save_yaml(out, run.to_dict(), _HEADER))
    return run
