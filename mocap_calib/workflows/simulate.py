"""``simulate``: write a simulated session with known truth."""

from __future__ import annotations

from dataclasses import MISSING, dataclass
from pathlib import Path

from mocap_calib.core.model.effects import CANONICAL_EFFECTS
from mocap_calib.core.params import param
from mocap_calib.errors import InputError
from mocap_calib.sim.flight import EFFECT_HELP, SIM_FAULTS
from mocap_calib.sim.motions import MOTIONS
from mocap_calib.workflows.outputs import Named, OutputPlan, output

#: What ``--effect`` accepts: every effect of the ladder and the mocap faults.
EFFECTS_DOC = "; ".join(f"{n}: {EFFECT_HELP[n]}" for n in (*CANONICAL_EFFECTS, *SIM_FAULTS))


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


    def plan(self) -> OutputPlan:
        """The session's files in OUT_DIR: ``mav0/imu0/data.csv`` (and ``mav0/vicon0/data.csv``
        for a flight) and ``truth.yaml``."""
        files = [self.out_dir / "mav0" / "imu0" / "data.csv", self.out_dir / "truth.yaml"]
        if self.protocol == "flight":
            files.insert(1, self.out_dir / "mav0" / "vicon0" / "data.csv")
        return OutputPlan.of(self, outputs=[Named("OUT_DIR", f) for f in files])


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
                              imu_rate=r.imu_rate, mocap_rate=r.mocap_rate,
                              effects=list(r.effect), mocap_noise_corr=r.mocap_noise_corr,
                              counts=r.counts, motion=r.motion, max_motion_hz=r.max_motion_hz)


def simulate_to_folder(out_dir: Path, *, protocol: str = "flight", seed: int = 0,
                       duration: float = 90.0, imu_rate: float = 200.0, mocap_rate: float = 100.0,
                       effects: list[str] | None = None,
                       mocap_noise_corr: float = 0.0, counts: bool = False,
                       motion: str = "flight", max_motion_hz: float = 0.0
                       ) -> list[tuple[Path, str]]:
    """Simulate a session and write it in the EuRoC layout plus ``truth.yaml``.

    Returns:
        ``(path, description)`` of every file written.
    """
    from mocap_calib.io.formats.euroc import write_euroc_imu, write_mav0
    from mocap_calib.io.yaml_io import check_writable, save_yaml
    from mocap_calib.sim.flight import SimConfig, parse_effect, simulate_flight

    out_dir = Path(out_dir)
    _check_folder(out_dir)
    check_writable(out_dir / "truth.yaml")
    parsed = dict(parse_effect(e) for e in (effects or []))
    if protocol == "multipos":
        from mocap_calib.workflows.imu.multipos import simulate_multipos_to_folder

        return simulate_multipos_to_folder(out_dir, seed=seed, rate_hz=imu_rate,
                                           effects=parsed, counts=counts)
    if counts:
        raise InputError("--counts applies to --protocol multipos only")
    header = "mocap-calib simulation truth (SI units). See docs/conventions.md."
    if (motion != "flight" or max_motion_hz) and protocol != "flight":
        raise InputError(f"--motion and --max-motion-hz apply to --protocol flight only, not "
                         f"'{protocol}'")
    if protocol == "flight":
        sim = simulate_flight(SimConfig(seed=seed, duration=duration, imu_rate=imu_rate,
                                        mocap_rate=mocap_rate, effects=parsed,
                                        mocap_noise_corr=mocap_noise_corr, motion=motion,
                                        max_motion_hz=max_motion_hz))
        mav0 = write_mav0(out_dir, sim.imu, sim.mocap)
        truth = save_yaml(out_dir / "truth.yaml", sim.truth, header)
        return [(mav0 / "imu0" / "data.csv", f"{len(sim.imu)} IMU samples at {imu_rate:g} Hz"),
                (mav0 / "vicon0" / "data.csv",
                 f"{len(sim.mocap)} mocap poses at {mocap_rate:g} Hz"),
                (truth, "true calibration, effects and noise")]
    if parsed:
        raise InputError(f"--effect applies to --protocol flight only, not '{protocol}'")
    if protocol == "static":
        from mocap_calib.sim.static import simulate_static

        imu, truth_d = simulate_static(seed=seed, duration_s=duration, rate_hz=imu_rate)
    else:
        raise InputError(f"unknown --protocol '{protocol}'; choose flight, multipos or static")
    path = write_euroc_imu(out_dir / "mav0" / "imu0" / "data.csv", imu)
    truth = save_yaml(out_dir / "truth.yaml", truth_d, header)
    return [(path, f"{len(imu)} IMU samples at {imu_rate:g} Hz ({protocol})"),
            (truth, "true intrinsics and noise")]
