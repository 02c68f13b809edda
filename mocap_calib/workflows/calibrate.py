"""Library functions behind the CLI commands: read the inputs, run the core, return results.

This is the outer layer that may use both ``io`` and ``core``; the CLI parses options, calls
one function here and writes what it returns.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mocap_calib.core.calib.pipeline import CalibrationOptions, IterationFn, ProgressFn, calibrate
from mocap_calib.core.calib.priors import priors_from_results
from mocap_calib.core.calib.result import CalibrationResult
from mocap_calib.core.model.types import ImuSamples, MocapPoses, NoiseModel
from mocap_calib.errors import InputError
from mocap_calib.io.loader import load_inputs
from mocap_calib.io.yaml_io import load_noise, load_result


@dataclass
class InputSpec:
    """Where the two streams come from and how to read them."""

    path: Path | None = None
    imu: Path | None = None
    mocap: Path | None = None
    pose_source: str = "auto"
    columns: str | None = None
    time_unit: str | None = None
    gyro_unit: str | None = None
    accel_unit: str | None = None
    quat_order: str | None = None
    position_unit: str | None = None
    rigid_body: str | None = None  # one body of a multi-body mocap export (a swarm's take)


@dataclass
class LoadedSession:
    imu: ImuSamples
    mocap: MocapPoses
    notes: list[str] = field(default_factory=list)
    sensor_noise: NoiseModel | None = None


def load_session(spec: InputSpec) -> LoadedSession:
    """Read both streams (and, from a ``mav0`` folder, the IMU's ``sensor.yaml`` noise)."""
    if spec.path is None and (spec.imu is None or spec.mocap is None):
        raise InputError("give a mav0 folder, or both --imu and --mocap")
    if spec.path is not None and (spec.imu is not None or spec.mocap is not None):
        raise InputError("give either a mav0 folder or --imu/--mocap, not both")
    if spec.rigid_body is not None:  # until the multi-body readers exist (issue 11)
        raise InputError(f"--rigid-body {spec.rigid_body}: this version reads mocap files "
                         "with one body only; export that body alone and drop --rigid-body")
    imu, mocap, notes = load_inputs(
        spec.imu, spec.mocap, spec.path, pose_source=spec.pose_source, columns=spec.columns,
        time_unit=spec.time_unit, gyro_unit=spec.gyro_unit, accel_unit=spec.accel_unit,
        quat_order=spec.quat_order, position_unit=spec.position_unit)
    sensor_noise = None
    if spec.path is not None:
        from mocap_calib.io.euroc import find_mav0

        root = find_mav0(spec.path)
        sensor = root / "imu0" / "sensor.yaml"
        if sensor.is_file():
            try:
                sensor_noise = load_noise(sensor)
                notes.append(f"noise densities from {sensor}")
            except InputError:
                sensor_noise = None
    return LoadedSession(imu, mocap, notes, sensor_noise)


def resolve_noise(session: LoadedSession, noise_file: Path | None,
                  overrides: dict[str, float | None]) -> NoiseModel:
    """Noise model: defaults < the mav0's ``imu0/sensor.yaml`` < ``--noise`` file < options."""
    noise = session.sensor_noise or NoiseModel()
    if noise_file is not None:
        noise = load_noise(noise_file, noise)
    given = {k: v for k, v in overrides.items() if v is not None}
    for k, v in given.items():
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"noise option {k.replace('_', '-')} must be positive, got {v}")
    return replace(noise, **given) if given else noise


def load_priors(paths: list[Path], at_ns: int) -> list:
    """Prior factors from one or more earlier results (a trend with two or more)."""
    results = [load_result(p) for p in paths]
    return priors_from_results(results, at_ns if len(results) > 1 else None)


def run_calibration(spec: InputSpec, options: CalibrationOptions, noise_file: Path | None = None,
                    noise_overrides: dict[str, float | None] | None = None,
                    prior_files: list[Path] | None = None, progress: ProgressFn | None = None,
                    on_iteration: IterationFn | None = None,
                    ) -> tuple[CalibrationResult, LoadedSession]:
    """Read the inputs and calibrate; returns the result and what was read."""
    session = load_session(spec)
    for note in session.notes:
        if progress is not None:
            progress(note)
    noise = resolve_noise(session, noise_file, noise_overrides or {})
    priors = load_priors(prior_files, session.imu.time_origin_ns) if prior_files else []
    opts = replace(options, noise=noise, priors=[*options.priors, *priors])
    result = calibrate(session.imu, session.mocap, opts, progress=progress,
                       on_iteration=on_iteration)
    result.session["inputs"] = list(session.notes)
    return result, session


def simulate_to_folder(out_dir: Path, *, protocol: str = "flight", seed: int = 0,
                       duration: float = 90.0, imu_rate: float = 200.0, mocap_rate: float = 100.0,
                       effects: list[str] | None = None) -> list[tuple[Path, str]]:
    """Simulate a session and write it in the EuRoC layout plus ``truth.yaml``.

    Returns:
        ``(path, description)`` of every file written.
    """
    from mocap_calib.io.euroc import write_euroc_imu, write_mav0
    from mocap_calib.io.yaml_io import save_yaml
    from mocap_calib.sim.flight import SimConfig, parse_effect, simulate_flight

    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is not a folder; choose another OUT_DIR")
    parsed = dict(parse_effect(e) for e in (effects or []))
    header = "mocap-calib simulation truth (SI units). See docs/conventions.md."
    if protocol == "flight":
        sim = simulate_flight(SimConfig(seed=seed, duration=duration, imu_rate=imu_rate,
                                        mocap_rate=mocap_rate, effects=parsed))
        mav0 = write_mav0(out_dir, sim.imu, sim.mocap)
        truth = save_yaml(out_dir / "truth.yaml", sim.truth, header)
        return [(mav0 / "imu0" / "data.csv", f"{len(sim.imu)} IMU samples at {imu_rate:g} Hz"),
                (mav0 / "vicon0" / "data.csv",
                 f"{len(sim.mocap)} mocap poses at {mocap_rate:g} Hz"),
                (truth, "true calibration, effects and noise")]
    if parsed:
        raise InputError(f"--effect applies to --protocol flight only, not '{protocol}'")
    if protocol == "multipos":
        from mocap_calib.sim.multipos import simulate_multipos

        imu, truth_d = simulate_multipos(seed=seed, rate_hz=imu_rate)
    elif protocol == "static":
        from mocap_calib.sim.static import simulate_static

        imu, truth_d = simulate_static(seed=seed, duration_s=duration, rate_hz=imu_rate)
    else:
        raise InputError(f"unknown --protocol '{protocol}'; choose flight, multipos or static")
    path = write_euroc_imu(out_dir / "mav0" / "imu0" / "data.csv", imu)
    truth = save_yaml(out_dir / "truth.yaml", truth_d, header)
    return [(path, f"{len(imu)} IMU samples at {imu_rate:g} Hz ({protocol})"),
            (truth, "true intrinsics and noise")]


def run_diagnosis(spec: InputSpec, options, noise_file: Path | None = None,
                  noise_overrides: dict[str, float | None] | None = None,
                  progress: ProgressFn | None = None):
    """Read the inputs and run the model diagnosis; returns the report and what was read."""
    from mocap_calib.core.diagnosis.diagnose import diagnose

    session = load_session(spec)
    for note in session.notes:
        if progress is not None:
            progress(note)
    noise = resolve_noise(session, noise_file, noise_overrides or {})
    opts = replace(options, calibration=replace(options.calibration, noise=noise))
    report = diagnose(session.imu, session.mocap, opts, progress=progress)
    report.final.session["inputs"] = list(session.notes)
    return report, session


def diagnose_series(report) -> list[tuple[str, dict]]:
    """Residual series of every diagnosis step, for the rerun recording: the low-band
    measured-minus-predicted gyro and accel, and the position-factor innovations."""
    from mocap_calib.core.calib.result import ResidualSeries

    out = []
    for i, step in enumerate(report.steps):
        series: dict = {}
        ra = step.residuals.analysis
        if ra is not None and len(ra.t):
            w = ra.keep.astype(float)
            series["gyro_lowpass"] = ResidualSeries(ra.t, ra.gyro_lp, ra.gyro_lp, w, "rad/s")
            series["accel_lowpass"] = ResidualSeries(ra.t, ra.accel_lp, ra.accel_lp, w, "m/s^2")
        if "position" in step.series:
            series["position"] = step.series["position"]
        label = f"{i}_{step.model}" if i < len(report.steps) - 1 else f"{i}_final_{step.model}"
        out.append((label, series))
    return out
