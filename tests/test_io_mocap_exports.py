"""Mocap exports in: Motive and Vicon CSVs written in those tools' documented layouts calibrate
to the simulator's truth (Y-up world, millimetres, occlusions, two rigid bodies in one file)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mocap_calib.cli.main import main
from mocap_calib.core.model import so3
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.io.formats.euroc import write_euroc_imu
from mocap_calib.io.loader import sniff_format
from mocap_calib.sim.flight import SimConfig, simulate_flight
from mocap_calib.workflows.calibrate import CalibrateRequest, InputSpec, run_calibration
from mocap_calib.workflows.session import MocapFormat

TD = 0.004
#: Motive's y-up world from the simulator's z-up one: x stays, y is up, z = -y_zup.
R_YUP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@pytest.fixture(scope="module")
def sim():
    return simulate_flight(SimConfig(seed=12, duration=60.0, effects={"time_offset": [TD]}))


def _occluded(n: int) -> np.ndarray:
    rows = np.zeros(n, dtype=bool)
    for start in (700, 2300, 4100):
        rows[start:start + 25] = True
    return rows


def _cells(values: np.ndarray, hide: np.ndarray) -> list[list[str]]:
    return [[""] * values.shape[1] if h else [repr(float(v)) for v in row]
            for row, h in zip(values, hide, strict=True)]


def write_motive(path: Path, sim, *, rotation_type: str = "Quaternion") -> Path:
    """Motive 1.23 CSV: two rigid bodies (the drone and a decoy), y-up, millimetres."""
    m = sim.mocap
    n = len(m)
    R = R_YUP @ m.rotation
    q = so3.rotmat_to_quat(R)  # wxyz
    p_mm = (m.position @ R_YUP.T) * 1000.0
    drone = np.concatenate([q[:, [1, 2, 3, 0]], p_mm, np.full((n, 1), 0.0002)], axis=1)
    decoy = np.concatenate([np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), np.full((n, 3), 500.0),
                            np.full((n, 1), 0.0003)], axis=1)
    meta = ["Format Version", "1.23", "Take Name", "flight", "Take Notes", "",
            "Capture Frame Rate", "100.000000", "Export Frame Rate", "100.000000",
            "Capture Start Time", "2020-09-13 12.26.40.000 PM", "Capture Start Frame", "0",
            "Total Frames in Take", str(n), "Total Exported Frames", str(n),
            "Rotation Type", rotation_type, "Length Units", "Millimeters",
            "Coordinate Space", "Global"]
    body = ["Rigid Body"] * 8
    lines = [",".join(meta), "",
             ",".join(["", "Type", *body, *body, "Marker", "Marker", "Marker"]),
             ",".join(["", "Name", *["decoy"] * 8, *["drone"] * 8, *["drone:Marker1"] * 3]),
             ",".join(["", "ID", *["1"] * 8, *["2"] * 8, *["3"] * 3]),
             ",".join(["", "", *(["Rotation"] * 4 + ["Position"] * 3 + ["Mean Marker Error"]) * 2,
                       "Position", "Position", "Position"]),
             ",".join(["Frame", "Time (Seconds)", *(["X", "Y", "Z", "W", "X", "Y", "Z", ""]) * 2,
                       "X", "Y", "Z"])]
    hide = _occluded(n)
    d_cells, o_cells = _cells(drone, hide), _cells(decoy, np.zeros(n, dtype=bool))
    for k in range(n):
        lines.append(",".join([str(k), f"{k / 100:.6f}", *o_cells[k], *d_cells[k], "", "", ""]))
    path.write_text("\n".join(lines) + "\n")
    return path


def write_vicon(path: Path, sim, *, section: str, rate: str = "100", rotation: str = "helical",
                names: tuple[str, str] = ("decoy:decoy", "drone:drone"),
                rot_unit: str = "deg") -> Path:
    """Vicon CSV: section, rate, subject names, RX..TZ columns, units row, frames from 1."""
    m = sim.mocap
    n = len(m)
    R = m.rotation
    if rotation == "helical":
        r = so3.log(R)
    else:  # R = Rx(a) Ry(b) Rz(c)
        b = np.arcsin(np.clip(R[:, 0, 2], -1, 1))
        a = np.arctan2(-R[:, 1, 2], R[:, 2, 2])
        c = np.arctan2(-R[:, 0, 1], R[:, 0, 0])
        r = np.stack([a, b, c], axis=1)
    scale = 180.0 / np.pi if rot_unit == "deg" else 1.0
    drone = np.concatenate([r * scale, m.position * 1000.0], axis=1)
    decoy = np.tile([0.0, 0.0, 0.0, 100.0, 200.0, 300.0], (n, 1))
    hide = _occluded(n)
    unit_cells = [rot_unit if rot_unit else ""] * 3 + ["mm"] * 3
    lines = [section, rate,
             ",".join(["", "", names[0], "", "", "", "", "", names[1], "", "", "", "", ""]),
             ",".join(["Frame", "Sub Frame", *["RX", "RY", "RZ", "TX", "TY", "TZ"] * 2]),
             ",".join(["", "", *unit_cells * 2])]
    d_cells, o_cells = _cells(drone, hide), _cells(decoy, np.zeros(n, dtype=bool))
    for k in range(n):
        lines.append(",".join([str(k + 1), "0", *o_cells[k], *d_cells[k]]))
    path.write_text("\n".join(lines) + "\n")
    return path


def _check_truth(result, sim, R_world: np.ndarray, t_d_expected: float) -> None:
    truth = sim.truth
    R_true = so3.quat_to_rotmat(np.asarray(truth["T_marker_imu"]["rotation_wxyz"]))
    err = so3.angle_deg(R_true.T @ result.R_marker_imu)
    assert err < 0.05, err
    assert np.linalg.norm(result.translation - truth["T_marker_imu"]["translation"]) < 2e-3
    assert np.max(np.abs(result.gyro_bias - truth["gyro_bias"])) < 2e-4
    assert np.max(np.abs(result.accel_bias - truth["accel_bias"])) < 5e-3
    g = R_world @ np.asarray(truth["gravity_in_mocap"])
    assert np.degrees(np.arccos(np.clip(g @ result.gravity_in_mocap, -1, 1))) < 0.02
    assert abs(result.time_offset - t_d_expected) < 2e-4


def _imu_csv(tmp_path: Path, sim) -> Path:
    return write_euroc_imu(tmp_path / "imu.csv", sim.imu)


def test_motive_export_calibrates_to_truth(sim, tmp_path) -> None:
    motive = write_motive(tmp_path / "take.csv", sim)
    assert sniff_format(motive) == "motive"
    spec = InputSpec(imu=_imu_csv(tmp_path, sim), mocap=motive,
                     poses=MocapFormat(rigid_body="drone"))
    result, session = run_calibration(CalibrateRequest(inputs=spec,
                                                       options=CalibrationOptions()))
    assert session.mocap.dropped_rows == 75
    # The capture start time is the simulator's mocap epoch: the clocks agree as simulated.
    _check_truth(result, sim, R_YUP, TD)
    assert result.gravity_in_mocap[1] < -0.99  # y-up world kept


@pytest.mark.parametrize("section,fmt,rotation,unit", [
    ("Segments", "vicon-nexus", "helical", "deg"),
    ("Objects", "vicon-tracker", "euler-xyz", ""),
])
def test_vicon_exports_calibrate_to_truth(sim, tmp_path, section, fmt, rotation, unit) -> None:
    names = (("decoy:decoy", "drone:drone") if fmt == "vicon-nexus"
             else ("Global Angle decoy:decoy", "Global Angle drone:drone"))
    vicon = write_vicon(tmp_path / "v.csv", sim, section=section, rotation=rotation,
                        names=names, rot_unit=unit or "rad")
    if not unit:  # Tracker: no rotation unit in the units row
        text = vicon.read_text().splitlines()
        text[4] = ",".join(["", "", "", "", "", "mm", "mm", "mm"] + ["", "", "", "mm", "mm", "mm"])
        vicon.write_text("\n".join(text) + "\n")
    assert sniff_format(vicon) == fmt
    spec = InputSpec(imu=_imu_csv(tmp_path, sim), mocap=vicon, poses=MocapFormat(
        rigid_body="drone", rotation=rotation + ("" if unit else ":rad")))
    result, session = run_calibration(CalibrateRequest(inputs=spec,
                                                       options=CalibrationOptions()))
    assert session.mocap.dropped_rows == 75
    # Vicon stamps are frame / rate from frame 1: the offset absorbs the IMU's epoch.
    epoch = sim.imu.time_origin_ns * 1e-9
    _check_truth(result, sim, np.eye(3), TD - epoch + 0.01)


def _one_line(capsys, code: int) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [x for x in err.strip().splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "Traceback" not in err, err
    return lines[0]


def test_bad_exports(sim, tmp_path, capsys) -> None:
    imu = str(_imu_csv(tmp_path, sim))
    out = ["--out", str(tmp_path / "o.yaml"), "-q"]
    euler = write_motive(tmp_path / "euler.csv", sim, rotation_type="XYZ")
    line = _one_line(capsys, main(["calibrate", "--imu", imu, "--mocap", str(euler), *out]))
    assert "euler.csv" in line and "Quaternion" in line
    two = write_motive(tmp_path / "two.csv", sim)
    line = _one_line(capsys, main(["calibrate", "--imu", imu, "--mocap", str(two), *out]))
    assert "decoy" in line and "drone" in line and "--rigid-body" in line
    norate = write_vicon(tmp_path / "norate.csv", sim, section="Objects", rate="",
                         names=("decoy", "drone"))
    line = _one_line(capsys, main(["calibrate", "--imu", imu, "--mocap", str(norate),
                                   "--rigid-body", "drone", "--rotation", "helical", *out]))
    assert "norate.csv" in line and "--mocap-rate" in line and "clock search" in line
    line = _one_line(capsys, main(["calibrate", "--imu", imu, "--mocap", str(norate),
                                   "--rigid-body", "drone", *out]))
    assert "--rotation" in line
    line = _one_line(capsys, main(["calibrate", "--imu", str(norate), "--mocap", imu, *out]))
    assert "--imu" in line and "Vicon" in line
    word = write_motive(tmp_path / "word.csv", sim)
    rows = word.read_text().splitlines()
    rows[-1] = "x1," + rows[-1].split(",", 1)[1]  # a word in the frame column
    word.write_text("\n".join(rows) + "\n")
    line = _one_line(capsys, main(["calibrate", "--imu", imu, "--mocap", str(word),
                                   "--rigid-body", "drone", *out]))
    assert "word.csv" in line and f"line {len(rows)}: 'x1' is not a number" in line


def test_vicon_without_rate_reads_with_mocap_rate(sim, tmp_path, capsys) -> None:
    from mocap_calib.io.formats.mocap_exports import ExportOptions, read_export

    norate = write_vicon(tmp_path / "norate.csv", sim, section="Objects", rate="",
                         names=("decoy", "drone"))
    notes: list[str] = []
    poses = read_export(norate, ExportOptions(rigid_body="drone", rotation="helical",
                                              mocap_rate=100.0), notes)
    keep = ~_occluded(len(sim.mocap))
    np.testing.assert_allclose(poses.position, sim.mocap.position[keep], atol=1e-12)
    assert np.array_equal(poses.stamps_ns(), (np.flatnonzero(keep) + 1) * 10_000_000)
    dots = np.abs(np.sum(poses.quat_wxyz * sim.mocap.quat_wxyz[keep], axis=1))
    assert np.all(dots > 1 - 1e-12)
