"""A simulated fleet for trying ``mocap-calib batch``: several airframes, each flown on several
dates, with biases that drift slowly from date to date, plus the manifest that lists them.

Each airframe keeps its rig (``SimConfig.rig_seed``: the same ``T_MI`` and room tilt every
date); every session flies its own trajectory. The simulator draws a fresh turn-on bias per
session, so the IMU samples are then shifted by a constant to put the session's true mean bias
on the airframe's straight line (a constant added to a measurement is exactly a bias change).
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mocap_calib.core.model.effects import CLOCK_OFFSET
from mocap_calib.core.model.parameters import ACCEL_BIAS, GYRO_BIAS
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.core.result.calibration import CalibrationResult

DAY_NS = 86_400 * 1_000_000_000


@dataclass(frozen=True)
class FleetSimConfig:
    """Fleet to simulate; rates are magnitudes per day along a random direction per airframe."""

    airframes: int = 2
    dates: int = 4
    days_between: int = 7
    first_date: dt.date = dt.date(2024, 3, 4)
    duration: float = 25.0
    gyro_bias_rate: float = 2e-4  # rad/s per day
    accel_bias_rate: float = 4e-3  # m/s^2 per day
    time_offset: float = 0.004  # s, every session
    seed: int = 0


def _direction(rng: np.random.Generator) -> np.ndarray:
    d = rng.normal(size=3)
    return d / np.linalg.norm(d)


def simulate_fleet(out_dir: Path, cfg: FleetSimConfig = FleetSimConfig()
                   ) -> tuple[Path, dict[str, Any]]:
    """Write every session as ``OUT_DIR/<id>/mav0`` (with its ``truth.yaml``) and
    ``OUT_DIR/manifest.yaml``.

    Returns:
        The manifest's path and the truth: per airframe the bias at the first date and the
        rates per day (``gyro_bias_rate``, ``accel_bias_rate``), per session its true biases.
    """
    from mocap_calib.io.formats.euroc import write_mav0
    from mocap_calib.io.yaml_io import save_yaml
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    out_dir = Path(out_dir)
    truth: dict[str, Any] = {"airframes": {}, "sessions": {}}
    sessions = []
    for a in range(cfg.airframes):
        imu_id = f"drone{a + 1}"
        rng = np.random.default_rng([cfg.seed, a])
        bg0, ba0 = rng.uniform(-0.02, 0.02, 3), rng.uniform(-0.1, 0.1, 3)
        rate_g = cfg.gyro_bias_rate * _direction(rng)
        rate_a = cfg.accel_bias_rate * _direction(rng)
        truth["airframes"][imu_id] = {"gyro_bias_first_date": bg0.tolist(),
                                      "accel_bias_first_date": ba0.tolist(),
                                      "gyro_bias_rate": rate_g.tolist(),
                                      "accel_bias_rate": rate_a.tolist()}
        for k in range(cfg.dates):
            days = k * cfg.days_between
            date = cfg.first_date + dt.timedelta(days=days)
            sid = f"{imu_id}-{date.isoformat()}"
            origin = int(dt.datetime(date.year, date.month, date.day, 10,
                                     tzinfo=dt.UTC).timestamp()) * 1_000_000_000
            sim = simulate_flight(SimConfig(
                seed=cfg.seed * 1000 + 10 * a + k, duration=cfg.duration, rig_seed=1000 + a,
                effects={CLOCK_OFFSET.name: [cfg.time_offset]}, imu_time_origin_ns=origin,
                mocap_time_origin_ns=origin))
            bg, ba = bg0 + days * rate_g, ba0 + days * rate_a
            drawn = CalibrationResult.from_dict(sim.truth)
            shift_g = bg - drawn.value(GYRO_BIAS)
            shift_a = ba - drawn.value(ACCEL_BIAS)
            imu = ImuSamples(sim.imu.t, sim.imu.gyro + shift_g, sim.imu.accel + shift_a,
                             sim.imu.time_origin_ns, sim.imu.source)
            biases = {GYRO_BIAS.value_key[-1]: bg.tolist(), ACCEL_BIAS.value_key[-1]: ba.tolist()}
            t = dict(sim.truth, **biases)
            t["simulation"] = dict(t["simulation"], bias_shift_gyro=shift_g.tolist(),
                                   bias_shift_accel=shift_a.tolist())
            write_mav0(out_dir / sid, imu, sim.mocap)
            save_yaml(out_dir / sid / "truth.yaml", t, "mocap-calib simulation truth (fleet)")
            truth["sessions"][sid] = {"imu_id": imu_id, "days": days, **biases}
            sessions.append({"id": sid, "imu_id": imu_id, "date": date.isoformat(),
                             "mav0": sid})
    manifest = save_yaml(out_dir / "manifest.yaml", {"sessions": sessions},
                         "mocap-calib batch manifest of a simulated fleet")
    return manifest, truth

