"""A batch manifest entry with several files per stream is one calibration of several takes
(``imu: [a, b]``, ``mocap: [a, b]``: the result's ``takes:``); unequal counts are refused in
one line that names the entry, before any work."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from mocap_calib.batch.manifest import ManifestError, load_manifest
from mocap_calib.cli.main import main
from mocap_calib.io.formats.euroc import write_euroc_imu, write_euroc_poses
from mocap_calib.sim.flight import SimConfig, simulate_flight

TAKES = ((41, 0.005), (42, -0.008))  # (seed, clock offset) of two takes of one rig


def _write(tmp: Path) -> list:
    sims = []
    for i, (seed, td) in enumerate(TAKES):
        sim = simulate_flight(SimConfig(seed=seed, duration=30.0, rig_seed=5,
                                        effects={"time_offset": [td]}))
        write_euroc_imu(tmp / f"imu{i}.csv", sim.imu)
        write_euroc_poses(tmp / f"mocap{i}.csv", sim.mocap)
        sims.append(sim)
    return sims


def _manifest(tmp: Path, imu: str, mocap: str) -> Path:
    path = tmp / "m.yaml"
    path.write_text(f"sessions:\n  - {{id: d1-0601, imu_id: d1, date: 2024-06-01, imu: {imu}, "
                    f"mocap: {mocap}, segments: 0}}\n")
    return path


@pytest.mark.slow
def test_several_files_per_entry_are_one_calibration_of_takes(tmp_path: Path) -> None:
    sims = _write(tmp_path)
    manifest = _manifest(tmp_path, "[imu0.csv, imu1.csv]", "[mocap0.csv, mocap1.csv]")
    assert main(["batch", str(manifest), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    d = yaml.safe_load((tmp_path / "out" / "d1-0601" / "calib.yaml").read_text())
    assert [Path(t["imu"]).name for t in d["takes"]] == ["imu0.csv", "imu1.csv"]
    assert [Path(t["mocap"]).name for t in d["takes"]] == ["mocap0.csv", "mocap1.csv"]
    for take, sim in zip(d["takes"], sims, strict=True):
        assert abs(take["time_offset"] - sim.truth["time_offset"]) < 0.3e-3
    assert d["time_offset"] is None and d["T_marker_imu"]["translation"] is not None
    # The consistency check compares the takes, each calibrated on its own.
    assert [x["take"] for x in d["consistency"]["takes"]["segments"]] == [1, 2]
    batch = yaml.safe_load((tmp_path / "out" / "batch.yaml").read_text())
    assert [s["status"] for s in batch["sessions"]] == ["ok"]


def test_unequal_counts_are_one_line_naming_the_entry(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    for name in ("imu0.csv", "imu1.csv", "mocap0.csv"):
        (tmp_path / name).write_text("t\n")
    manifest = _manifest(tmp_path, "[imu0.csv, imu1.csv]", "[mocap0.csv]")
    with pytest.raises(ManifestError) as err:
        load_manifest(manifest)
    assert err.value.problems == [
        f"{manifest}: session 'd1-0601' (#1): 2 imu and 1 mocap files; several takes are given "
        "as lists of pairs, in order: imu: [a, b] with mocap: [a, b] (the same file twice when "
        "one file holds both streams)"]
    capsys.readouterr()
    assert main(["batch", str(manifest), "--out", str(tmp_path / "out")]) == 2
    err_text = capsys.readouterr().err
    assert err_text.count("\n") == 1 and "session 'd1-0601'" in err_text
    assert not (tmp_path / "out").exists()
