"""Library functions behind the mocap-free IMU commands: ``multipos``, ``allan``, ``drift``.

Outer layer (may use ``io`` and ``core``): read the IMU log (and, for ``drift``, the
calibration and optional mocap poses), run one core algorithm, and return a run object whose
``to_dict()`` is the YAML to write and whose ``summary()`` is the text to print. The CLI only
parses options, calls one ``run_*`` function here and writes its output.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.intrinsics.allan import AllanResult, SensorNoise, characterise_noise
from mocap_calib.core.intrinsics.attitude_drift import (
    AttitudeDriftResult,
    GyroCalibration,
    attitude_drift_check,
)
from mocap_calib.core.intrinsics.multipos import (
    PARAMETERS,
    MultiposPrior,
    MultiposResult,
    calibrate_multipos,
)
from mocap_calib.core.model import so3
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.errors import CalibrationError, InputError, input_error
from mocap_calib.io.loader import (
    FORMAT_NAMES,
    is_recording,
    load_imu_file,
    load_inputs,
    sniff_format,
)
from mocap_calib.io.yaml_io import NOISE_KEYS, load_yaml

Array = NDArray[np.float64]
ProgressFn = Callable[[str], None]

#: Parameters a multipos prior constrains by default: the matrices. Turn-on biases change from
#: one power-up to the next by more than a session's sigma, so they are opt-in.
PRIOR_DEFAULT_NAMES: tuple[str, ...] = ("accel_matrix", "gyro_matrix")

_MULTIPOS_FIX = "pass an intrinsics YAML written by 'mocap-calib multipos'"
_CALIB_FIX = ("pass a result of 'mocap-calib calibrate' or intrinsics of 'mocap-calib "
              "multipos'")


def _say(progress: ProgressFn | None, message: str) -> None:
    if progress is not None:
        progress(message)


@contextmanager
def _option_names(names: Mapping[str, str]) -> Iterator[None]:
    """Re-raise the core's errors with its keyword names replaced by the CLI's options
    (``init_static_s`` -> ``--init-static``), so the fix in the message can be typed.

    Args:
        names: regular expression -> replacement.
    """
    try:
        yield
    except CalibrationError as err:
        msg = str(err)
        for pattern, new in names.items():
            msg = re.sub(pattern, new, msg)
        if msg == str(err):
            raise
        raise type(err)(msg) from None


# --------------------------------------------------------------------------------------------
# IMU-only input
# --------------------------------------------------------------------------------------------

@dataclass
class ImuSpec:
    """Where the IMU log comes from and how to read it (options of ``cli/common.py``).

    Attributes:
        imu: EuRoC ``imu0/data.csv``, a ``mav0`` folder (or its parent), or a generic CSV.
        columns: column map of a generic CSV (``--columns``).
        time_unit: s, ms, us or ns; None for the format's own.
        gyro_unit: rad/s or deg/s; None for the format's own.
        accel_unit: m/s^2 or g; None for the format's own.
    """

    imu: Path | None = None
    columns: str | None = None
    time_unit: str | None = None
    gyro_unit: str | None = None
    accel_unit: str | None = None
    imu_topic: str | None = None  # bags and ULogs (io.loader.load_imu_file)
    stamp: str = "header"

    def units(self) -> dict[str, str]:
        """The unit options that were given (the reader's defaults stand for the rest)."""
        return {k: v for k, v in (("time_unit", self.time_unit), ("gyro_unit", self.gyro_unit),
                                  ("accel_unit", self.accel_unit)) if v is not None}


def load_imu(spec: ImuSpec) -> tuple[ImuSamples, list[str]]:
    """Read an IMU log without mocap (``io.loader.load_inputs`` needs both streams).

    Format as in :mod:`mocap_calib.io.loader`: a folder is an EuRoC ``mav0``; a file with the
    EuRoC ``imu0`` header is EuRoC; anything else is a generic CSV that needs ``columns``.

    Returns:
        The samples and one-line notes for the user.

    Raises:
        InputError: no ``--imu``, missing file, pose file given, unknown format, bad rows.
    """
    from mocap_calib.io.euroc import find_mav0, read_euroc_imu
    from mocap_calib.io.generic import read_generic

    if spec.imu is None:
        raise input_error("no --imu given", "pass the IMU log with --imu FILE")
    path = Path(spec.imu)
    if is_recording(path):  # bags and ULogs
        return load_imu_file(path, topic=spec.imu_topic, stamp=spec.stamp)
    fmt = sniff_format(path)
    notes: list[str] = []
    if fmt in ("mav0", "euroc_imu"):
        file = find_mav0(path) / "imu0" / "data.csv" if fmt == "mav0" else path
        if spec.columns is not None:
            notes.append(f"ignored --columns for {path}: it is an {FORMAT_NAMES[fmt]}")
        imu = read_euroc_imu(file, **spec.units())
    elif fmt == "euroc_poses" or (fmt == "tum" and spec.columns is None):
        raise input_error(f"--imu is given a pose file ({FORMAT_NAMES[fmt]}), not an IMU log",
                          "pass the IMU file (EuRoC imu0/data.csv layout or a CSV with "
                          "--columns)", str(path))
    else:
        if spec.columns is None:
            raise input_error("format not recognised (not an EuRoC imu0 CSV)",
                              "say which columns hold what with --columns, e.g. "
                              "--columns 't=0,gyro=1:4,accel=4:7'", str(path))
        read, _ = read_generic(path, spec.columns, streams=["imu"], **spec.units())
        assert read is not None
        imu, file = read, path
    notes.append(f"IMU: {len(imu)} samples at {imu.rate_hz:.1f} Hz over {imu.duration:.1f} s "
                 f"({FORMAT_NAMES[fmt]} {file})")
    return imu, notes


# --------------------------------------------------------------------------------------------
# Table helper
# --------------------------------------------------------------------------------------------

def _table(header: Sequence[str], rows: Sequence[Sequence[str]], right: Sequence[bool]) -> str:
    """Columns padded to their widest cell; ``right`` aligns numeric columns right."""
    w = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]

    def line(r: Sequence[str]) -> str:
        return "  ".join(f"{c:>{w[i]}}" if right[i] else f"{c:<{w[i]}}"
                         for i, c in enumerate(r)).rstrip()

    return "\n".join([line(header), "-" * (sum(w) + 2 * (len(w) - 1)), *map(line, rows)])


# --------------------------------------------------------------------------------------------
# multipos
# --------------------------------------------------------------------------------------------

def read_intrinsics(path: Path | str) -> dict[str, Any]:
    """Read and check a multipos intrinsics YAML (values and sigmas of every parameter).

    Raises:
        InputError: the file is missing, is another kind of file (a calibrate result, a noise
            file, a simulator truth without sigmas) or has malformed entries.
    """
    data = load_yaml(path, "multipos intrinsics file")
    if "T_marker_imu" in data:
        raise InputError(f"{path}: is a 'mocap-calib calibrate' result, not multipos "
                         f"intrinsics; {_MULTIPOS_FIX}")
    if any(k in data for k in NOISE_KEYS):
        raise InputError(f"{path}: is a noise file (Kalibr imu.yaml keys), not multipos "
                         f"intrinsics; {_MULTIPOS_FIX}")
    sigma = data.get("sigma")
    for name, shape in PARAMETERS.items():
        if name not in data:
            raise InputError(f"{path}: no '{name}'; {_MULTIPOS_FIX}")
        if not isinstance(sigma, dict) or sigma.get(name) is None:
            raise InputError(f"{path}: no 'sigma: {{{name}: ...}}' (a simulator truth file has "
                             f"no sigmas); {_MULTIPOS_FIX}")
        for what, value in (("", data[name]), ("sigma of ", sigma[name])):
            try:
                arr = np.asarray(value, dtype=float)
            except (TypeError, ValueError):
                arr = np.zeros(0)
            if arr.shape != shape:
                raise InputError(f"{path}: {what}'{name}' must be {shape} numbers; "
                                 f"{_MULTIPOS_FIX}")
    return data


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
    dicts = [read_intrinsics(p) for p in paths]
    names = tuple(PARAMETERS) if include_biases else PRIOR_DEFAULT_NAMES
    files = ", ".join(str(p) for p in paths)
    if len(dicts) == 1:
        prior = MultiposPrior.from_result(dicts[0], names=names, sigma_scale=sigma_scale)
    else:
        times = []
        for p, d in zip(paths, dicts, strict=True):
            diag = d.get("diagnostics")
            stamp = diag.get("session_time_ns") if isinstance(diag, dict) else None
            if not isinstance(stamp, int | float):
                raise InputError(f"{p}: no 'diagnostics: {{session_time_ns: ...}}', needed for "
                                 f"a trend over several priors; {_MULTIPOS_FIX}")
            times.append(float(stamp) * 1e-9)
        prior = MultiposPrior.from_history(dicts, times_s=times, at_time_s=at_time_s,
                                           names=names, sigma_scale=sigma_scale)
    return replace(prior, source=f"{prior.source} ({files}; {', '.join(names)})")


def _misalignment_label(i: int, j: int) -> str:
    return f"{'xyz'[i]}{'xyz'[j]}"


@dataclass
class MultiposRun:
    """A multipos calibration and what it was computed from.

    Attributes:
        result: the intrinsics with 1-sigma, residuals and diagnostics.
        imu: the IMU log.
        notes: one-line notes (inputs, prior).
    """

    result: MultiposResult
    imu: ImuSamples
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """The conventions' intrinsics keys, ``sigma``, ``residuals``, ``diagnostics``, and
        the inputs."""
        d = self.result.to_dict()
        d["inputs"] = list(self.notes)
        return d

    def summary(self) -> str:
        """Table of the intrinsics (scale errors in %, misalignments in deg), the fit figures
        and the poorly determined parameters."""
        r = self.result
        rows: list[tuple[str, str, str, str]] = []
        for sensor, M, S, lower in (("accel", r.accel_matrix, r.accel_matrix_sigma, True),
                                    ("gyro", r.gyro_matrix, r.gyro_matrix_sigma, False)):
            d = np.diag(M)
            for i in range(3):
                rows.append((f"{sensor} scale error {'xyz'[i]}", f"{100 * (d[i] - 1):+.4f}",
                             f"{100 * S[i, i]:.4f}", "%"))
            # M = diag(s) (I + E): the misalignment angle of entry (i, j) is E_ij = M_ij / s_i.
            for i in range(3):
                for j in range(3):
                    if i == j or (lower and j > i):
                        continue
                    rows.append((f"{sensor} misalignment {_misalignment_label(i, j)}",
                                 f"{np.degrees(M[i, j] / d[i]):+.4f}",
                                 f"{np.degrees(S[i, j] / d[i]):.4f}", "deg"))
            bias = getattr(r, f"{sensor}_bias")
            bsig = getattr(r, f"{sensor}_bias_sigma")
            unit = "m/s^2" if sensor == "accel" else "rad/s"
            for i in range(3):
                rows.append((f"{sensor} bias {'xyz'[i]}", f"{bias[i]:+.6f}", f"{bsig[i]:.2g}",
                             unit))
        lines = [_table(("parameter", "estimate", "1-sigma", "unit"), rows,
                        (False, True, True, False)), ""]
        lines.append(f"accel residual RMS  {1e3 * r.accel_residual_rms:.3g} mm/s^2 "
                     f"(|h| - g over the static intervals; chi2/dof {r.accel_chi2:.3g})")
        lines.append(f"gyro residual RMS   {np.degrees(r.gyro_residual_rms):.3g} deg "
                     f"(gravity direction after each rotation; chi2/dof {r.gyro_chi2:.3g})")
        lines.append(f"static detector     threshold multiple k = {r.threshold_multiple:g}, "
                     f"{r.n_static_intervals} static intervals, "
                     f"{r.n_distinct_orientations} distinct orientations")
        if r.prior_source is not None:
            lines.append(f"prior               {r.prior_source}")
        lines.append("model               a_m = M_a f + b_a, w_m = M_g w + b_g "
                     "(M = diag(1 + scale error) (I + misalignment))")
        if r.poorly_determined:
            lines.append("")
            lines += [f"POORLY DETERMINED {p}" for p in r.poorly_determined]
        else:
            lines.append("poorly determined   none")
        return "\n".join(lines)


def run_multipos(spec: ImuSpec, *, init_static_s: float = 30.0, window_s: float = 1.0,
                 min_interval_s: float = 0.5, gravity: float = 9.81, min_orientations: int = 9,
                 prior_files: Sequence[Path] = (), prior_biases: bool = False,
                 prior_sigma_scale: float = 1.0, progress: ProgressFn | None = None
                 ) -> MultiposRun:
    """Read an IMU log and calibrate its intrinsics from a multi-position session.

    Args:
        spec: the IMU log.
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
    prior_files = list(prior_files)
    # Check the priors before the (longer) IMU read so a wrong file fails fast.
    for p in prior_files:
        read_intrinsics(p)
    _say(progress, f"reading {spec.imu}")
    imu, notes = load_imu(spec)
    for n in notes:
        _say(progress, n)
    prior = None
    if prior_files:
        prior = load_multipos_prior(prior_files, float(imu.stamps_ns()[0]) * 1e-9,
                                    include_biases=prior_biases, sigma_scale=prior_sigma_scale)
        notes.append(f"prior: {prior.source}")
        _say(progress, f"prior: {prior.source}")
    _say(progress, "detecting static intervals and fitting accelerometer and gyroscope")
    with _option_names({r"\binit_static_s\b": "--init-static", r"\bwindow_s\b": "--window",
                        r"\bmin_interval_s\b": "--min-interval",
                        r"\bmin_orientations\b": "--min-orientations",
                        r"^gravity=": "--gravity "}):
        result = calibrate_multipos(imu, init_static_s=init_static_s, window_s=window_s,
                                    min_interval_s=min_interval_s, gravity=gravity,
                                    min_orientations=min_orientations, prior=prior)
    return MultiposRun(result, imu, notes)


# --------------------------------------------------------------------------------------------
# allan
# --------------------------------------------------------------------------------------------

_ALLAN_UNITS = {"gyroscope": ("rad/s/sqrt(Hz)", "rad/s^2/sqrt(Hz)", "rad/s"),
                "accelerometer": ("m/s^2/sqrt(Hz)", "m/s^3/sqrt(Hz)", "m/s^2")}


@dataclass
class AllanRun:
    """A noise characterisation and what it was computed from.

    Attributes:
        result: the noise model per axis and the Allan curves.
        imu: the static log.
        notes: one-line notes (inputs).
    """

    result: AllanResult
    imu: ImuSamples
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """Kalibr ``imu.yaml`` keys first (as :meth:`AllanResult.to_dict`), then the inputs."""
        d = self.result.to_dict()
        d["inputs"] = list(self.notes)
        return d

    def summary(self) -> str:
        """Per-axis table of N, K, B (with 1-sigma) and the Kalibr values written."""
        r = self.result
        rows: list[tuple[str, ...]] = []

        def pm(v: float, s: float) -> str:
            if not np.isfinite(v):
                return "unresolved"
            return f"{v:.4g} +- {s:.2g}" if np.isfinite(s) else f"{v:.4g}"

        s: SensorNoise
        for s in (r.gyroscope, r.accelerometer):
            for ax in range(3):
                rows.append((s.sensor, "xyz"[ax],
                             pm(s.noise_density[ax], s.noise_density_sigma[ax]),
                             pm(s.random_walk[ax], s.random_walk_sigma[ax]),
                             f"{s.bias_instability[ax]:.4g}", f"{s.tau_at_minimum[ax]:.4g}",
                             f"{s.fit_chi2[ax]:.3g}"))
        lines = [_table(("sensor", "axis", "noise density N", "random walk K",
                         "bias instab. B", "tau(min) s", "chi2"), rows,
                        (False, False, True, True, True, True, True)),
                 "units: gyroscope N rad/s/sqrt(Hz), K rad/s^2/sqrt(Hz), B rad/s; "
                 "accelerometer N m/s^2/sqrt(Hz), K m/s^3/sqrt(Hz), B m/s^2", ""]
        d = r.to_dict()
        lines.append(f"Kalibr imu.yaml ({r.aggregate} over the axes, {r.rate_hz:.4g} Hz, "
                     f"{r.duration_s / 3600:.2f} h log):")
        for sensor, (nu, ku, _) in _ALLAN_UNITS.items():
            for key, unit in ((f"{sensor}_noise_density", nu), (f"{sensor}_random_walk", ku)):
                v = d[key]
                lines.append(f"  {key + ':':<32} "
                             f"{'null (not resolved)' if v is None else f'{v:.6g}'}  {unit}")
        for k, why in d.get("unobservable", {}).items():
            lines.append(f"UNOBSERVABLE {k}: {why}")
        return "\n".join(lines)


def run_allan(spec: ImuSpec, *, aggregate: str = "mean", tau_min_s: float | None = None,
              require_random_walk: bool = True, progress: ProgressFn | None = None) -> AllanRun:
    """Read a long static IMU log and fit its Allan-deviation noise model.

    Args:
        spec: the IMU log.
        aggregate: ``mean`` or ``max`` over the axes for the Kalibr keys.
        tau_min_s: shortest averaging time fitted (s); None: one sample.
        require_random_walk: fail when the log does not resolve the random walks (otherwise
            they are written as null).
        progress: one-line progress callback.

    Raises:
        InputError: bad input files, timestamps or options.
        ObservabilityError: the log is too short, moves, or does not resolve the random walk.
    """
    if aggregate not in ("mean", "max"):
        raise InputError(f"--aggregate {aggregate}: use mean or max")
    if tau_min_s is not None and not (np.isfinite(tau_min_s) and tau_min_s > 0):
        raise InputError(f"--tau-min {tau_min_s}: must be a positive time in s")
    _say(progress, f"reading {spec.imu}")
    imu, notes = load_imu(spec)
    for n in notes:
        _say(progress, n)
    _say(progress, "computing overlapping Allan deviations and fitting N, B, K per axis")
    with _option_names({r"pass require_random_walk=False": "pass --allow-unresolved"}):
        result = characterise_noise(imu, aggregate=aggregate,  # type: ignore[arg-type]
                                    tau_min_s=tau_min_s,
                                    require_random_walk=require_random_walk)
    return AllanRun(result, imu, notes)


# --------------------------------------------------------------------------------------------
# drift
# --------------------------------------------------------------------------------------------

@dataclass
class DriftCalibration:
    """A calibration file turned into what the drift check needs.

    Attributes:
        kind: ``calibrate`` (a mocap calibration result) or ``multipos`` (intrinsics).
        values: dict for :meth:`GyroCalibration.from_dict` (``gyro_bias``, ``gyro_matrix``,
            ``g_sensitivity``, ``accel_bias``, ``accel_matrix``).
        R_MI: rotation of ``T_marker_imu`` (calibrate results), else None.
        gravity_dir: ``gravity_in_mocap`` (calibrate results), else None.
        time_offset: clock offset ``t_d`` in s (0 when not given).
        gyro_bias_rate: ``r_g`` of ``gyro_bias_drift`` in rad/s^2, or None.
        session_span_ns: (first, last) IMU stamp of the calibration's session, when known.
        notes: one-line notes.
    """

    kind: str
    values: dict[str, Any]
    R_MI: Array | None = None
    gravity_dir: Array | None = None
    time_offset: float = 0.0
    gyro_bias_rate: Array | None = None
    session_span_ns: tuple[int, int] | None = None
    notes: list[str] = field(default_factory=list)


def _vec(value: Any, shape: tuple[int, ...], path: Path, name: str) -> Array | None:
    if value is None:
        return None
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = np.zeros(0)
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise InputError(f"{path}: '{name}' must be {shape} finite numbers; {_CALIB_FIX}")
    return arr


def read_calibration(path: Path | str) -> DriftCalibration:
    """Read a calibrate result or multipos intrinsics YAML for the drift check.

    Raises:
        InputError: missing file, another kind of file, or malformed entries.
    """
    path = Path(path)
    data = load_yaml(path, "calibration file")
    if "T_marker_imu" in data:
        from mocap_calib.io.yaml_io import load_result

        res = load_result(path)  # checks version and keys
        if res.gyro_bias is None:
            raise InputError(f"{path}: the gyro bias is null (unobservable in that session); "
                             "the drift check needs it")
        values: dict[str, Any] = {"gyro_bias": res.gyro_bias, "accel_bias": res.accel_bias}
        rate = None
        for name, rec in (res.effects or {}).items():
            if not isinstance(rec, Mapping):
                continue
            for key in ("gyro_matrix", "g_sensitivity", "accel_matrix"):
                if rec.get(key) is not None:
                    values[key] = _vec(rec[key], (3, 3), path, f"effects.{name}.{key}")
            if rec.get("gyro_bias_rate") is not None:
                rate = _vec(rec["gyro_bias_rate"], (3,), path, f"effects.{name}.gyro_bias_rate")
        R_MI = None
        if res.rotation_wxyz is not None:
            q = _vec(res.rotation_wxyz, (4,), path, "T_marker_imu.rotation_wxyz")
            assert q is not None
            R_MI = so3.quat_to_rotmat(q / np.linalg.norm(q))
        g = _vec(res.gravity_in_mocap, (3,), path, "gravity_in_mocap")
        span = None
        start, dur = res.session.get("imu_start_ns"), res.session.get("duration_s")
        if isinstance(start, int) and isinstance(dur, int | float):
            span = (start, start + int(round(float(dur) * 1e9)))
        return DriftCalibration("calibrate", values, R_MI,
                                None if g is None else g / np.linalg.norm(g),
                                float(res.time_offset or 0.0), rate, span)
    if "accel_matrix" in data and "gyro_matrix" in data:
        values = {}
        for name, shape in PARAMETERS.items():
            values[name] = _vec(data.get(name), shape, path, name)
        if values["gyro_bias"] is None:
            raise InputError(f"{path}: no 'gyro_bias'; {_CALIB_FIX}")
        span = None
        diag = data.get("diagnostics")
        if isinstance(diag, dict) and isinstance(diag.get("session_time_ns"), int):
            iv = np.asarray(diag.get("static_intervals_s") or [[0.0, 0.0]], dtype=float)
            t0 = int(diag["session_time_ns"])
            span = (t0, t0 + int(round(float(np.max(iv)) * 1e9)))
        return DriftCalibration("multipos", values, session_span_ns=span)
    if any(k in data for k in NOISE_KEYS):
        raise InputError(f"{path}: is a noise file (Kalibr imu.yaml keys), not a calibration; "
                         f"{_CALIB_FIX}")
    raise InputError(f"{path}: not a calibration (no 'T_marker_imu' or 'gyro_matrix'); "
                     f"{_CALIB_FIX}")


#: A mocap interval longer than this many median intervals is a gap (occlusion).
_MOCAP_GAP_FACTOR = 2.5


def _reference_on_imu_times(imu_t: Array, t_ref: Array, R_ref: Array, t0: float, t1: float
                            ) -> tuple[Array, Array]:
    """Mocap IMU attitudes moved onto IMU sample times in ``[t0, t1]``.

    The core compares the integrated attitude at the first IMU sample at or after each
    reference time; with the reference on IMU stamps that comparison is exact instead of up to
    one IMU period late (which, in fast rotation, reads as drift). Attitudes are interpolated
    geodesically between the neighbouring mocap samples, at about the mocap rate (plus both
    segment ends); IMU times inside a mocap gap are left out.

    Raises:
        InputError: the segment starts or ends inside a mocap gap.
    """
    i0 = int(np.searchsorted(imu_t, t0, side="left"))
    i1 = int(np.searchsorted(imu_t, t1, side="right")) - 1
    if i1 <= i0:
        raise InputError(f"segment [{t0:g}, {t1:g}] s holds fewer than 2 IMU samples")
    dt_ref = np.diff(t_ref)
    step = max(1, int(round(float(np.median(dt_ref)) / float(np.median(np.diff(imu_t))))))
    idx = np.unique(np.concatenate([np.arange(i0, i1 + 1, step), [i0, i1]]))
    t = imu_t[idx]
    j = np.clip(np.searchsorted(t_ref, t, side="right"), 1, len(t_ref) - 1)
    gap = dt_ref[j - 1] > _MOCAP_GAP_FACTOR * float(np.median(dt_ref))
    for end, what in ((0, "start"), (-1, "end")):
        if gap[end]:
            raise InputError(f"the mocap has a gap ({dt_ref[j[end] - 1]:.2f} s) at the "
                             f"segment's {what} (t={t[end]:.3f} s on the IMU clock); move "
                             f"--{what} to where the marker is tracked")
    keep = ~gap
    t, j = t[keep], j[keep]
    a = j - 1
    frac = np.clip((t - t_ref[a]) / (t_ref[j] - t_ref[a]), 0.0, 1.0)
    Ra = R_ref[a]
    rel = so3.log(np.einsum("nji,njk->nik", Ra, R_ref[j]))
    return t, Ra @ so3.exp(frac[:, None] * rel)


@dataclass
class DriftRun:
    """An attitude-drift check and what it was computed from.

    Attributes:
        result: roll/pitch/tilt drift raw and calibrated.
        calibration: the calibration file read.
        calibration_file: its path.
        notes: one-line notes.
    """

    result: AttitudeDriftResult
    calibration: DriftCalibration
    calibration_file: Path
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        d = self.result.to_dict()
        d["calibration"] = {"file": str(self.calibration_file), "kind": self.calibration.kind}
        d["notes"] = list(self.notes)
        return d

    def summary(self) -> str:
        """Roll, pitch and tilt drift before/after and the reduction."""
        r = self.result
        rows = [(what, f"{getattr(r, f'{key}_drift_raw_deg'):+.4f}",
                 f"{getattr(r, f'{key}_drift_cal_deg'):+.4f}")
                for what, key in (("roll drift", "roll"), ("pitch drift", "pitch"),
                                  ("tilt drift (angle)", "tilt"))]
        src = {"reference": "mocap", "accel": "accelerometer at rest"}
        lines = [f"segment {r.t0:.3f} - {r.t1:.3f} s after the IMU start ({r.duration:.1f} s); "
                 f"initial attitude: {src.get(r.initial_source, r.initial_source)}, reference: "
                 f"{src.get(r.reference_source, r.reference_source)}",
                 f"calibration: {self.calibration_file} ({self.calibration.kind})", "",
                 _table(("at the segment end", "raw gyro (deg)", "calibrated (deg)"), rows,
                        (False, True, True)), "",
                 f"reduction of the tilt drift: {100 * r.reduction:.1f} %"]
        if len(r.series_t):
            lines.append(f"along the mocap reference: max tilt drift raw "
                         f"{np.max(r.series_tilt_raw_deg):.4f} deg, calibrated "
                         f"{np.max(r.series_tilt_cal_deg):.4f} deg")
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


def run_drift(spec: ImuSpec, calibration: Path, start: float, end: float, *,
              mocap: Path | None = None, quat_order: str | None = None,
              position_unit: str | None = None, static_window_s: float = 1.0,
              progress: ProgressFn | None = None) -> DriftRun:
    """Attitude-drift check of a calibration over a segment of an IMU log.

    The gyro is integrated over ``[start, end]`` (s after the IMU log's first sample) raw and
    calibrated, from the same initial attitude; roll and pitch are compared with the
    reference at ``end``. With ``mocap``, the attitudes are ``R_WM R_MI`` (``R_MI`` from the
    calibration's ``T_marker_imu``, mocap times moved onto the IMU clock with its
    ``time_offset``, gravity along its ``gravity_in_mocap``), else roll and pitch come from
    the accelerometer, and the IMU must rest at ``start`` and ``end``.

    Raises:
        InputError: bad files or options, ``start >= end``, segment outside the log, mocap
            with a calibration that has no ``T_marker_imu``.
        ObservabilityError: no mocap and the IMU is not at rest at ``start`` or ``end``.
    """
    if not (np.isfinite(start) and np.isfinite(end)):
        raise InputError("--start and --end must be finite times in s")
    if not start < end:
        raise InputError(f"--start {start:g} s must be before --end {end:g} s")
    if not static_window_s > 0:
        raise InputError(f"--static-window {static_window_s:g}: must be positive")
    cal = read_calibration(calibration)
    notes = list(cal.notes)
    if mocap is not None and cal.R_MI is None:
        raise InputError(f"{calibration}: has no T_marker_imu, so mocap attitudes cannot be "
                         "turned into IMU attitudes; pass a 'mocap-calib calibrate' result, or "
                         "leave out --mocap to use the accelerometer at rest")
    _say(progress, f"reading {spec.imu}" + (f" and {mocap}" if mocap is not None else ""))
    if mocap is None:
        imu, read_notes = load_imu(spec)
        poses = None
    else:
        imu, poses, read_notes = load_inputs(
            spec.imu, mocap, None, columns=spec.columns, time_unit=spec.time_unit,
            gyro_unit=spec.gyro_unit, accel_unit=spec.accel_unit, quat_order=quat_order,
            position_unit=position_unit)
    for n in read_notes:
        _say(progress, n)
    if start < 0 or end > imu.duration + 1e-9:
        raise InputError(f"segment [{start:g}, {end:g}] s is outside the IMU log, which spans "
                         f"0-{imu.duration:.3f} s after its first sample; choose --start and "
                         "--end inside it")
    t0 = float(imu.t[0]) + start
    t1 = float(imu.t[0]) + end

    values = dict(cal.values)
    stamps = imu.stamps_ns()
    seg_ns = (int(stamps[0]) + int(round(start * 1e9)), int(stamps[0]) + int(round(end * 1e9)))
    if cal.gyro_bias_rate is not None:
        if cal.session_span_ns is not None:
            # b_g(t) = b_g + r_g (t - t_mid): the bias at the segment's middle.
            mid_cal = 0.5 * (cal.session_span_ns[0] + cal.session_span_ns[1])
            dt = (0.5 * (seg_ns[0] + seg_ns[1]) - mid_cal) * 1e-9
            values["gyro_bias"] = np.asarray(values["gyro_bias"]) + cal.gyro_bias_rate * dt
            notes.append(f"gyro bias moved by its drift rate to the segment's middle "
                         f"({dt:+.1f} s from the calibration's)")
        else:
            notes.append("gyro_bias_rate ignored: the calibration file does not say when its "
                         "session was")
    if cal.session_span_ns is not None and (seg_ns[0] < cal.session_span_ns[1]
                                            and seg_ns[1] > cal.session_span_ns[0]):
        notes.append("the segment overlaps the session the calibration was computed from; "
                     "the check is optimistic on data the calibration has seen")

    kwargs: dict[str, Any] = {"static_window_s": static_window_s}
    if poses is not None:
        assert cal.R_MI is not None
        # tau = u + (origin_imu - origin_mocap) 1e-9 + t_d  (core/session.py): mocap -> IMU clock.
        shift = (poses.time_origin_ns - imu.time_origin_ns) * 1e-9
        t_ref = poses.t + shift - cal.time_offset
        if t_ref[0] > t0 or t_ref[-1] < t1:
            raise InputError(f"the mocap poses cover {t_ref[0] - imu.t[0]:.3f}-"
                             f"{t_ref[-1] - imu.t[0]:.3f} s after the IMU start, not the whole "
                             f"segment [{start:g}, {end:g}] s; choose a segment inside both")
        kwargs["reference_series"] = _reference_on_imu_times(
            imu.t, t_ref, poses.rotation @ cal.R_MI, t0, t1)
        if cal.gravity_dir is not None:
            kwargs["gravity_dir"] = cal.gravity_dir
        else:
            notes.append("gravity_in_mocap is null in the calibration: mocap -z taken as down")
    _say(progress, f"integrating the gyro over [{start:g}, {end:g}] s, raw and calibrated")
    with _option_names({"give a mocap attitude": "pass --mocap",
                        "choose a time when the IMU rests": "move --start/--end to where the "
                        "IMU rests"}):
        result = attitude_drift_check(imu, t0, t1, GyroCalibration.from_dict(values),
                                      **kwargs)
    # Report times relative to the log's first sample, as the options are given.
    result = replace(result, t0=result.t0 - float(imu.t[0]), t1=result.t1 - float(imu.t[0]),
                     series_t=result.series_t - float(imu.t[0]))
    return DriftRun(result, cal, Path(calibration), notes)
