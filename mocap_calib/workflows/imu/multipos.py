"""``mocap-calib multipos``: read an IMU log (and earlier intrinsics as a prior), calibrate its
intrinsics from a multi-position session, write the intrinsics YAML."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
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
from mocap_calib.core.intrinsics.multipos.units import RawConversion
from mocap_calib.core.model.effects import of_term
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.core.params import group, param
from mocap_calib.core.policy import GRAVITY
from mocap_calib.errors import ConvergenceError, InputError
from mocap_calib.io.result_files import INTRINSICS_FIX, read_intrinsics
from mocap_calib.io.yaml_io import INTRINSICS_NUMBERS, non_finite, save_yaml
from mocap_calib.report.intrinsics_text import multipos_summary
from mocap_calib.workflows.calibrate import HTML_HELP
from mocap_calib.workflows.imu.imu_input import CropSpec, ImuSpec, ProgressFn, say
from mocap_calib.workflows.outputs import OutputPlan, Product, output, write_products
from mocap_calib.workflows.report_files.provenance import RunClock

#: Parameters a multipos prior constrains by default: the matrices. Turn-on biases change from
#: one power-up to the next by more than a session's sigma, so they are opt-in.
PRIOR_DEFAULT_NAMES: tuple[str, ...] = ("accel_matrix", "gyro_matrix")

#: How the core's messages name the options: as the command line spells them.
CLI_NAMES = {"init_static_s": "--init-static", "window_s": "--window",
             "min_interval_s": "--min-interval", "min_orientations": "--min-orientations",
             "gravity": "--gravity", "accel_scale": "--accel-scale",
             "accel_offset": "--accel-offset", "g_sensitivity": "--g-sensitivity"}

_HEADER = ("mocap-calib multipos intrinsics (SI units; 1-sigma under 'sigma').\n"
           "a_m = M_a f + b_a (accel_matrix lower-triangular), w_m = M_g w + G f + b_g (G: "
           "g_sensitivity, if modelled).\nRaw counts: a_m = scale (raw - offset) per "
           "'raw_input'; imu_tk's T K (raw - b) under 'imu_tk'. See docs/conventions.md.")


def load_multipos_prior(paths: Sequence[Path], at_time_s: float, *,
                        include_biases: bool = False, sigma_scale: float = 1.0,
                        raw: bool = False) -> MultiposPrior:
    """Prior from earlier multipos intrinsics: one file as is, two or more as a trend.

    Args:
        paths: earlier intrinsics YAMLs written by ``mocap-calib multipos``.
        at_time_s: the new session's time (s since the Unix epoch of the stamps) to extrapolate
            the first-order trend to (used with two or more files).
        include_biases: constrain ``accel_bias`` and ``gyro_bias`` too (default: only the
            matrices, which are stable; turn-on biases are not).
        sigma_scale: multiply the prior's sigmas by this (> 1 allows for change since then).
        raw: the new session is in raw counts: the priors must be raw-count calibrations too
            (their values are taken in counts, whatever nominal units each was written in).

    Raises:
        InputError: a file is not multipos intrinsics, is of the other kind of input (raw or
            SI), or has no session time for a trend.
    """
    if not (np.isfinite(sigma_scale) and sigma_scale > 0):
        raise InputError(f"--prior-sigma-scale must be positive, got {sigma_scale}")
    results = [read_intrinsics(p) for p in paths]
    for p, r in zip(paths, results, strict=True):
        if (r.raw_input is not None) != raw:
            what = "raw counts (--raw)" if r.raw_input is not None else "SI units"
            raise InputError(f"{p}: is a calibration of {what}, this session is not; give "
                             "priors calibrated from the same kind of readings")
    if raw:
        counts = RawConversion.identity("counts")
        results = [r.in_units(counts) for r in results]
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
    return replace(prior, source=f"{prior.source} ({files}; {', '.join(names)})", counts=raw)


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


def _numbers(value: str | Sequence[float], key: str) -> list[float]:
    """``"v"`` or ``"v1,v2,v3"`` (or numbers) as 1 or 3 floats."""
    try:
        out = [float(v) for v in (value.split(",") if isinstance(value, str) else value)]
    except ValueError:
        out = []
    if len(out) not in (1, 3):
        raise InputError(f"--{key.replace('_', '-')} {value}: give 1 or 3 comma-separated "
                         "numbers")
    return out


@dataclass
class MultiposOptions:
    """The command's calibration options (``mocap-calib multipos --help``); the nominal
    conversion of raw counts (1 or 3 numbers each) is only the starting point and the units of
    the result, and applies with ``--raw`` only."""

    init_static: float = param(30.0, "length of the initial rest period (30-50 recommended)",
                               unit="s", lo=1.0, hi=3600.0)
    window: float = param(1.0, "static-detector window", unit="s", lo=0.05, hi=60.0)
    min_interval: float = param(0.5, "shortest static interval used", unit="s", lo=0.05,
                                hi=60.0)
    min_orientations: int = param(9, "fewest distinct static orientations accepted", lo=3,
                                  hi=1000)
    gravity: float = param(GRAVITY, "local |g|", unit="m/s^2", lo=5.0, hi=15.0)
    threshold: tuple[float, ...] = param(
        (), "static-detector threshold multiple k to try (repeatable; default 2..10): static "
        "where |var_w(a)| < k |var_init(a)|, imu_tk's meaning", lo=0.0, lo_open=True,
        show_default=False)
    g_sensitivity: str = param(
        "auto", "the gyro's g-sensitivity G (w_m = M_g w + G f + b_g): auto (kept if a "
        "likelihood-ratio test on the static poses says so), on or off",
        choices=("auto", "on", "off"))
    accel_scale: str | None = param(
        None, "with --raw: nominal accelerometer scale, m/s^2 per count (1 or 3 values, e.g. "
        "0.0023942 for 4096 LSB/g); default: found from the data", show_default=False)
    accel_offset: str | None = param(
        None, "with --raw: nominal accelerometer offset, counts (1 or 3 values; e.g. 32768 for "
        "unsigned output)", show_default=False)
    gyro_scale: str | None = param(None, "with --raw: nominal gyro scale, rad/s per count (1 "
                                   "or 3 values)", show_default=False)
    gyro_offset: str | None = param(None, "with --raw: nominal gyro offset, counts",
                                    show_default=False)
    prior: tuple[Path, ...] = param(
        (), "earlier intrinsics YAML from 'mocap-calib multipos' as a prior (repeatable; two "
        "or more give a first-order trend extrapolated to this session's time)",
        metavar="PATH", show_default=False)
    prior_biases: bool = param(
        False, "let the prior constrain the biases too (default: only the matrices; turn-on "
        "biases change between power-ups)", decls=("--prior-biases",))
    prior_sigma_scale: float = param(
        1.0, "multiply the prior's sigmas by this (> 1 allows for change since then)",
        lo=0.0, lo_open=True)

    def nominal(self, raw: bool) -> RawConversion | None:
        """The nominal conversion of raw counts, or None."""
        given = {k: _numbers(getattr(self, k), k) for k in (
            "accel_scale", "accel_offset", "gyro_scale", "gyro_offset")
            if getattr(self, k) is not None}
        if not given:
            return None
        if not raw:
            raise InputError(f"--{next(iter(given)).replace('_', '-')} applies to raw counts: "
                             "pass --raw too")
        if "accel_scale" not in given or "gyro_scale" not in given:
            raise InputError("give both --accel-scale and --gyro-scale (nominal m/s^2 and "
                             "rad/s per count), or neither (the starting point is then found "
                             "from the data)")
        try:
            return RawConversion(given["accel_scale"], given.get("accel_offset", [0.0]),
                                 given["gyro_scale"], given.get("gyro_offset", [0.0]), "given")
        except ValueError as err:
            raise InputError(f"nominal scale/offset: {err}; give 1 or 3 numbers, scales "
                             "positive") from None


@dataclass
class MultiposRequest:
    """Everything ``multipos`` can be told."""

    imu: ImuSpec = group(ImuSpec, "Input")
    crop: CropSpec = group(CropSpec, "Input")
    options: MultiposOptions = group(MultiposOptions, "Calibration")
    out: Path = output(Path("intrinsics.yaml"), "intrinsics YAML to write", metavar="PATH")
    html: Path | None = output(None, HTML_HELP, metavar="PATH", show_default=False)
    quiet: bool = param(False, "no progress lines", decls=("--quiet", "-q"))

    def plan(self) -> OutputPlan:
        return OutputPlan.of(self)


def run_multipos(request: MultiposRequest, progress: ProgressFn | None = None) -> MultiposRun:
    """Read an IMU log, calibrate its intrinsics from a multi-position session, and write them.

    Raises:
        InputError: bad input files or options.
        ObservabilityError: no initial rest, too short, too few orientations.
        ConvergenceError: a fit failed.
    """
    spec, out, html, o = request.imu, request.out, request.html, request.options
    clock = RunClock()
    request.plan().check()
    nominal = o.nominal(spec.raw)
    prior_files = list(o.prior)
    # Check the priors before the (longer) IMU read so a wrong file fails fast.
    for p in prior_files:
        read_intrinsics(p)
    say(progress, f"reading {spec.name}")
    imu, notes = spec.load(request.crop)
    for n in notes:
        say(progress, n)
    prior = None
    if prior_files:
        prior = load_multipos_prior(prior_files, float(imu.stamps_ns()[0]) * 1e-9,
                                    include_biases=o.prior_biases,
                                    sigma_scale=o.prior_sigma_scale, raw=spec.raw)
        notes.append(f"prior: {prior.source}")
        say(progress, f"prior: {prior.source}")
    say(progress, "detecting static intervals and fitting accelerometer and gyroscope")
    result = calibrate_multipos(
        imu, init_static_s=o.init_static, window_s=o.window,
        min_interval_s=o.min_interval, gravity=o.gravity,
        min_orientations=o.min_orientations, prior=prior, names=CLI_NAMES, raw=spec.raw,
        nominal=nominal, g_sensitivity=o.g_sensitivity,
        threshold_multiples=tuple(o.threshold) or tuple(range(2, 11)))
    run = MultiposRun(result, imu, notes)
    bad = non_finite(run.to_dict(), INTRINSICS_NUMBERS)
    if bad:
        raise ConvergenceError(f"{bad}, not a number intrinsics can have (no trustworthy "
                               "solution); nothing written: check the session")

    def page() -> None:
        from mocap_calib.workflows.report_files.intrinsics import write_multipos_html

        write_multipos_html(html, result, imu, [spec.imu, spec.accel, spec.gyro, *prior_files],
                            clock)

    written = write_products([
        None if out is None else Product("--out", out,
                                         lambda: save_yaml(out, run.to_dict(), _HEADER)),
        None if html is None else Product("--html", html, page, step="writing HTML report"),
    ], progress)
    run.written = [p.path for p in written]
    return run


def simulate_multipos_to_folder(out_dir: Path, *, seed: int = 0, rate_hz: float = 200.0,
                                effects: Mapping[str, list[float] | None] | None = None,
                                counts: bool = False) -> list[tuple[Path, str]]:
    """Simulate a multi-position session and write it in the EuRoC layout plus ``truth.yaml``.

    Args:
        out_dir: folder to write into.
        seed: random seed.
        rate_hz: IMU rate.
        effects: parsed ``--effect`` options; only ``gyro_g_sensitivity`` (the std of ``G``'s
            entries, or its 9 values; default :data:`~mocap_calib.sim.multipos.G_STD`).
        counts: write raw counts of a 16-bit part (``truth.yaml``: ``counts`` has the nominal
            scales and offsets; the intrinsics are for the SI readings they convert to).

    Returns:
        ``(path, description)`` of every file written.
    """
    from mocap_calib.io.formats.euroc import write_euroc_imu
    from mocap_calib.sim.multipos import G_STD, CountsSpec, simulate_multipos

    effects = dict(effects or {})
    g_sens = of_term("gyro", "f").name  # the only effect a multi-position log simulates
    other = [e for e in effects if e != g_sens]
    if other:
        raise InputError(f"--effect {other[0]} does not apply to --protocol multipos (only "
                         f"{g_sens}; the intrinsics are always simulated)")
    G: float | list[float] | None = None
    if g_sens in effects:
        value = effects[g_sens]
        G = G_STD if value is None else (value[0] if len(value) == 1 else value)
    imu, truth = simulate_multipos(seed=seed, rate_hz=rate_hz, g_sensitivity=G,
                                   counts=CountsSpec() if counts else None)
    path = write_euroc_imu(Path(out_dir) / "mav0" / "imu0" / "data.csv", imu)
    header = "mocap-calib simulation truth (SI units). See docs/conventions.md."
    if counts:
        header += ("\nThe IMU file holds raw counts (column headers notwithstanding): "
                   "x = scale (raw - offset) per 'counts'.")
    truth_path = save_yaml(Path(out_dir) / "truth.yaml", truth, header)
    what = f"{len(imu)} IMU samples at {rate_hz:g} Hz (multipos" + (
        ", raw 16-bit counts)" if counts else ")")
    return [(path, what), (truth_path, "true intrinsics and noise")]
