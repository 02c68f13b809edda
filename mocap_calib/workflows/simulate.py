"""``simulate``: write a simulated session with known truth."""

from __future__ import annotations

from dataclasses import MISSING, dataclass, fields
from pathlib import Path
from typing import Any

from mocap_calib.core.params import param
from mocap_calib.errors import InputError
from mocap_calib.sim.injected import effect_help, injectable
from mocap_calib.sim.motions import MOTIONS
from mocap_calib.sim.presets import PRESET_HELP, PRESETS
from mocap_calib.workflows.outputs import Named, OutputPlan, output

#: What ``--effect`` accepts: every effect of the ladder and the stream faults.
EFFECTS_DOC = "; ".join(f"{n}: {effect_help(n)}" for n in injectable())


@dataclass
class SimulateRequest:
    """Everything ``simulate`` can be told."""

    out_dir: Path = output(MISSING, "folder to write the session into", kind="folder",
                           argument=True, metavar="OUT_DIR")
    seed: int = param(0, "random seed (same seed, same output)", lo=0)
    duration: float = param(90.0, "session length", unit="s", lo=1.0, lo_open=True)
    imu_rate: float = param(200.0, "IMU rate", unit="Hz", lo=1.0, hi=1e5)
    mocap_rate: float = param(100.0, "mocap rate", unit="Hz", lo=1.0, hi=1e4)
    effect: tuple[str, ...] = param(
        (), "inject an effect (repeatable); without a value a realistic magnitude is drawn. "
        + EFFECTS_DOC, decls=("--effect", "-e"), metavar="NAME[=VALUE]", show_default=False)
    mocap_noise_corr: float = param(
        0.0, "mocap noise correlated over this time constant (AR(1) with the same per-sample "
        "sigma), as real mocap noise is; 0: white", unit="s", lo=0.0, hi=60.0)
    protocol: str = param(
        "flight", "flight: a drone flight in a mocap room; multipos: static orientations for "
        "'mocap-calib multipos' (no mocap); static: a still IMU for 'mocap-calib allan'",
        choices=("flight", "multipos", "static"))
    counts: bool = param(
        False, "with --protocol multipos: write raw counts of a 16-bit MEMS part (+-8 g, "
        "+-2000 deg/s; truth.yaml gives the nominal scales) for 'multipos --raw'",
        decls=("--counts",))
    motion: str = param(
        "flight", "with --protocol flight: flight (rotates about all axes), turntable (one "
        "vertical axis), planar (a ground robot: yaw and planar translation) or slow (low "
        "excitation); the last three cannot determine everything",
        choices=tuple(MOTIONS))
    max_motion_hz: float = param(
        0.0, "with --motion flight: add motion from 1 Hz up to this (1-20 Hz, at most a fifth "
        "of the mocap rate), as a vibrating or aggressive flight has; 0: off", unit="Hz",
        lo=1.0, hi=20.0, also=(0.0,))
    preset: str = param(
        "none", "with --protocol flight: a named regime; options left at their defaults take "
        "its values, others override them. " + "; ".join(f"{k}: {v}" for k, v in
                                                          PRESET_HELP.items()),
        choices=tuple(PRESETS))
    vibration: float = param(
        0.0, "rotor vibration: RMS of its specific force over the three axes (4 rotors "
        "wandering in 95-145 Hz with their 2nd harmonic, mostly along the IMU's z axis, "
        "sampled at the IMU rate so that it aliases); 0: off", unit="m/s^2", lo=0.0, hi=100.0)
    vibration_gyro: float = param(
        0.0, "the rotor vibration's angular rate, RMS over the three axes; 0: off",
        unit="rad/s", lo=0.0, hi=10.0)
    anti_alias_hz: float = param(
        0.0, "cut-off of a first-order low-pass on the vibration ahead of the IMU's sampling; "
        "0: none", unit="Hz", lo=1.0, hi=1e4, also=(0.0,))
    accel_noise_factor: float = param(
        1.0, "white accelerometer noise as a multiple of the data sheet's density (truth.yaml "
        "records the true one)", lo=0.0, lo_open=True, hi=1000.0)
    gyro_noise_factor: float = param(
        1.0, "white gyro noise as a multiple of the data sheet's density", lo=0.0,
        lo_open=True, hi=1000.0)

    def plan(self) -> OutputPlan:
        """The session's files in OUT_DIR: ``mav0/imu0/data.csv`` (and ``mav0/vicon0/data.csv``
        for a flight) and ``truth.yaml``."""
        files = [self.out_dir / "mav0" / "imu0" / "data.csv", self.out_dir / "truth.yaml"]
        if self.protocol == "flight":
            files.insert(1, self.out_dir / "mav0" / "vicon0" / "data.csv")
        return OutputPlan.of(self, outputs=[Named("OUT_DIR", f) for f in files])


#: Options of a flight that a preset sets, and the SimConfig / Vibration field of each.
_FLIGHT_KNOBS = ("imu_rate", "mocap_rate", "mocap_noise_corr", "motion", "max_motion_hz",
                 "accel_noise_factor", "gyro_noise_factor")
_VIBRATION_KNOBS = {"vibration": "accel_rms", "vibration_gyro": "gyro_rms",
                    "anti_alias_hz": "anti_alias_hz"}


def _check_folder(out_dir: Path) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is not a folder; choose another OUT_DIR")


def _refuse_recording(plan: OutputPlan, out_dir: Path) -> None:
    """A folder that holds a recording but no simulator truth is a user's data, not an earlier
    simulation: its files are not replaced."""
    if (out_dir / "truth.yaml").is_file():
        return
    held = [o.path for o in plan.outputs if o.path.exists()]
    if held:
        raise InputError(f"OUT_DIR {out_dir}: holds {held[0]} and no truth.yaml, a recording "
                         "rather than a simulation; simulate into another folder")


def simulate_request(request: SimulateRequest) -> list[tuple[Path, str]]:
    """``simulate`` from its request (see :func:`simulate_to_folder`)."""
    r = request
    plan = r.plan()
    _check_folder(Path(r.out_dir))
    _refuse_recording(plan, Path(r.out_dir))
    plan.check()
    return simulate_to_folder(r.out_dir, protocol=r.protocol, seed=r.seed, duration=r.duration,
                              effects=list(r.effect), counts=r.counts, preset=r.preset,
                              **{k: getattr(r, k) for k in (*_FLIGHT_KNOBS, *_VIBRATION_KNOBS)})


def _given(values: dict[str, Any]) -> dict[str, Any]:
    """The options whose values differ from their defaults (the rest take the preset's)."""
    defaults = {f.name: f.default for f in fields(SimulateRequest)}
    return {k: v for k, v in values.items() if v != defaults[k]}


def simulate_to_folder(out_dir: Path, *, protocol: str = "flight", seed: int = 0,
                       duration: float = 90.0, effects: list[str] | None = None,
                       counts: bool = False, preset: str = "none", **knobs: Any
                       ) -> list[tuple[Path, str]]:
    """Simulate a session and write it in the EuRoC layout plus ``truth.yaml``.

    ``knobs``: the flight's options of :class:`SimulateRequest` (``imu_rate``,
    ``mocap_noise_corr``, ``vibration``, ...); those left at their defaults take the
    preset's values.

    Returns:
        ``(path, description)`` of every file written.
    """
    from mocap_calib.io.formats.euroc import write_euroc_imu
    from mocap_calib.io.yaml_io import check_writable, save_yaml
    from mocap_calib.sim.flight import parse_effect

    unknown = set(knobs) - {*_FLIGHT_KNOBS, *_VIBRATION_KNOBS}
    if unknown:
        raise TypeError(f"simulate_to_folder: unknown options {sorted(unknown)}")
    given = _given(knobs)
    out_dir = Path(out_dir)
    _check_folder(out_dir)
    check_writable(out_dir / "truth.yaml")
    parsed = dict(parse_effect(e) for e in (effects or []))
    if counts and protocol != "multipos":
        raise InputError("--counts applies to --protocol multipos only")
    if protocol == "flight":
        return _flight(out_dir, preset, seed, duration, parsed, given)
    flight_only = [f"--{k.replace('_', '-')}" for k in given if k != "imu_rate"]
    if flight_only or preset != "none":
        raise InputError(f"{', '.join(flight_only + (['--preset'] if preset != 'none' else []))}"
                         f": for --protocol flight only, not '{protocol}'")
    imu_rate = knobs.get("imu_rate", 200.0)
    if protocol == "multipos":
        from mocap_calib.workflows.imu.multipos import simulate_multipos_to_folder

        return simulate_multipos_to_folder(out_dir, seed=seed, rate_hz=imu_rate,
                                           effects=parsed, counts=counts)
    if parsed:
        raise InputError(f"--effect applies to --protocol flight only, not '{protocol}'")
    if protocol != "static":
        raise InputError(f"unknown --protocol '{protocol}'; choose flight, multipos or static")
    from mocap_calib.sim.static import simulate_static

    imu, truth_d = simulate_static(seed=seed, duration_s=duration, rate_hz=imu_rate)
    path = write_euroc_imu(out_dir / "mav0" / "imu0" / "data.csv", imu)
    truth = save_yaml(out_dir / "truth.yaml", truth_d, _HEADER)
    return [(path, f"{len(imu)} IMU samples at {imu_rate:g} Hz ({protocol})"),
            (truth, "true intrinsics and noise")]


_HEADER = "mocap-calib simulation truth (SI units). See docs/conventions.md."


def _flight(out_dir: Path, preset: str, seed: int, duration: float,
            effects: dict[str, list[float] | None], given: dict[str, Any]
            ) -> list[tuple[Path, str]]:
    """A flight of ``preset`` with the options ``given`` over it, written to ``out_dir``."""
    from mocap_calib.io.formats.euroc import write_mav0
    from mocap_calib.io.yaml_io import save_yaml
    from mocap_calib.sim.flight import simulate_flight
    from mocap_calib.sim.presets import preset_config

    vibration = {_VIBRATION_KNOBS[k]: given.pop(k) for k in list(given) if k in _VIBRATION_KNOBS}
    sim = simulate_flight(preset_config(preset, vibration, seed=seed, duration=duration,
                                        effects=effects, **given))
    info = sim.truth["simulation"]
    mav0 = write_mav0(out_dir, sim.imu, sim.mocap)
    truth = save_yaml(out_dir / "truth.yaml", sim.truth, _HEADER)
    return [(mav0 / "imu0" / "data.csv", f"{len(sim.imu)} IMU samples at "
             f"{info['imu_rate']:g} Hz"),
            (mav0 / "vicon0" / "data.csv", f"{len(sim.mocap)} mocap poses at "
             f"{info['mocap_rate']:g} Hz"),
            (truth, "true calibration, effects and noise"
             + (f" (preset {preset})" if preset != "none" else ""))]
