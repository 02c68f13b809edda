"""Priors are used visibly and tested against the session's data: a prior the data contradict
refuses the run in one line (exit 2) unless ``--trust-prior`` keeps it (noted and
marked); a consistent prior is used and noted; a trend names every file; a prior on an IMU
intrinsic is tested the same way; a batch session with a conflicting history fails alone.

What the data alone say is checked against a full calibration without the prior (the
pipeline's own answer, not the check's refit)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocap_calib.cli.main import main
from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.parameters import GRAVITY_DIRECTION, ROTATION, TRANSLATION
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.errors import InputError
from mocap_calib.io.formats.euroc import write_mav0
from mocap_calib.io.yaml_io import save_result
from mocap_calib.sim.flight import SimConfig, simulate_flight
from mocap_calib.workflows.session import load_priors

pytestmark = pytest.mark.slow  # full calibrations with and without priors: not in the quick subset

RIG = 77
DAY_NS = 86400 * 10**9
#: An IMU whose accelerometer matrix every simulated session shares (M_a - I, row-major; the
#: upper triangle is not part of the lower-triangular model).
ACCEL_MATRIX = [0.006, 0.0, 0.0, 0.002, -0.005, 0.0, -0.003, 0.001, 0.004]
MODEL = "base+time_offset+accel_scale_misalignment"
FAST = {"segments": 0, "sensitivity": False, "effect_tests": False}


def _flight(seed: int, duration: float = 30.0, rig: int | None = RIG):
    return simulate_flight(SimConfig(seed=seed, duration=duration, rig_seed=rig,
                                     effects={"accel_scale_misalignment": ACCEL_MATRIX}))


def _options(**kw) -> CalibrationOptions:
    return CalibrationOptions(model=Model.parse(MODEL), **FAST, **kw)


def _cli(argv: list[str], capsys) -> tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def _one_line(err: str) -> str:
    lines = [x for x in err.splitlines() if x.strip()]
    assert "Traceback" not in err
    assert lines and lines[-1].startswith("error:"), err
    return lines[-1]


# --- the command line: the reproduction ----------------------------------------------------

@pytest.fixture(scope="module")
def cli_session(tmp_path_factory) -> tuple[Path, dict]:
    """A 40 s session in the EuRoC layout, its calibration without priors (a.yaml) and a prior
    50 mm off along x with the session's own 0.17 mm sigma (bad_prior.yaml)."""
    d = tmp_path_factory.mktemp("prior_cli")
    sim = simulate_flight(SimConfig(seed=7, duration=40.0))
    write_mav0(d / "s", sim.imu, sim.mocap)
    assert main(["calibrate", str(d / "s"), "--out", str(d / "a.yaml"), "-q"]) == 0
    a = yaml.safe_load((d / "a.yaml").read_text())
    bad = yaml.safe_load((d / "a.yaml").read_text())
    bad["T_marker_imu"]["translation"][0] += 0.05
    bad["sigma"]["translation"] = [0.00017] * 3
    (d / "bad_prior.yaml").write_text(yaml.safe_dump(bad))
    return d, a


def test_a_conflicting_prior_is_refused_in_one_line(cli_session, capsys) -> None:
    d, _ = cli_session
    capsys.readouterr()
    code, _, err = _cli(["calibrate", str(d / "s"), "--prior", str(d / "bad_prior.yaml"),
                         "--out", str(d / "b.yaml"), "-q"], capsys)
    assert code == 2, err
    line = _one_line(err)
    for word in ("bad_prior.yaml", "as a --prior", "p_MI", "z ", "--trust-prior",
                 "remounted"):
        assert word in line, line
    size = float(re.search(r"p_MI is ([0-9.]+) mm", line).group(1))
    assert 47.0 < size < 53.0, line  # the 50 mm the prior was moved by, give or take the data's
    assert not (d / "b.yaml").exists()


def test_the_option_keeps_a_conflicting_prior_marked(cli_session, capsys) -> None:
    d, a = cli_session
    capsys.readouterr()
    code, out, err = _cli(["calibrate", str(d / "s"), "--prior", str(d / "bad_prior.yaml"),
                           "--trust-prior", "--out", str(d / "k.yaml")], capsys)
    assert code == 0, err
    k = yaml.safe_load((d / "k.yaml").read_text())
    section = k["priors"]
    assert section["kept_conflicting"] and section["checked"]
    blocks = {b["parameter"]: b for b in section["blocks"]}
    assert set(blocks) == {"rotation", "translation", "gravity"}
    t = blocks["translation"]
    assert t["conflict"] and t["statistic"] > t["threshold"] and abs(t["z"][0]) > 10
    assert t["sources"] == [str(d / "bad_prior.yaml")]
    assert not blocks["rotation"]["conflict"] and not blocks["gravity"]["conflict"]
    # What the data alone say is what the calibration without the prior said.
    alone = np.asarray(t["data_alone"]["value"])
    np.testing.assert_allclose(alone, a["T_marker_imu"]["translation"],
                               atol=3 * max(t["data_alone"]["sigma"]))
    notes = [n for n in k["notes"] if "priors used from" in n]
    assert len(notes) == 1 and "CONFLICTING" in notes[0] and "p_MI" in notes[0]
    assert "priors (" in out and "CONFLICT" in out  # the text summary


# --- the library: consistent priors, a trend, an intrinsic ---------------------------------

@pytest.fixture(scope="module")
def rig(tmp_path_factory) -> dict:
    """Two earlier sessions of one rig (their results as files, a day apart) and a new one,
    with the new one's calibration without priors."""
    d = tmp_path_factory.mktemp("prior_lib")
    new = _flight(2)
    files = []
    for k, seed in enumerate((1, 3)):
        r = calibrate(*_streams(_flight(seed)), _options())
        r.session["imu_start_ns"] = new.imu.time_origin_ns - (2 - k) * DAY_NS
        files.append(save_result(d / f"earlier_{seed}.yaml", r))
    alone = calibrate(new.imu, new.mocap, _options())
    return {"dir": d, "files": files, "new": new, "alone": alone}


def _streams(sim):
    return sim.imu, sim.mocap


def test_a_consistent_prior_is_used_and_noted(rig) -> None:
    new, alone = rig["new"], rig["alone"]
    priors = load_priors(rig["files"][1:], new.imu.time_origin_ns)
    r = calibrate(new.imu, new.mocap, _options(priors=priors))
    assert r.priors is not None and r.priors.checked and not r.priors.conflicts
    blocks = {b.block: b for b in r.priors.blocks}
    assert set(blocks) == {"rotation", "translation", "gravity", "accel_scale_misalignment"}
    assert all(b.sources == (str(rig["files"][1]),) for b in blocks.values())
    notes = [n for n in r.notes if n.startswith("priors used from")]
    assert len(notes) == 1 and str(rig["files"][1]) in notes[0] and "agrees" in notes[0]
    # The data-alone values are the calibration without the prior's, within a fraction of
    # their sigma; the answer is the two combined: it moved from the data's value towards the
    # prior's by the prior's share of the information (per component), within half its sigma.
    for p, b in ((TRANSLATION, blocks["translation"]),
                 (GRAVITY_DIRECTION, blocks["gravity"]), (ROTATION, blocks["rotation"])):
        full = p.state(alone.value(p))
        refit = p.state(np.asarray(b.data_value))
        assert np.all(np.abs(p.difference(full, refit)) < 0.3 * np.asarray(b.data_sigma)), p
        moved = p.difference(refit, p.state(r.value(p)))
        var_d, var_p = np.square(b.data_sigma), np.square(b.prior_sigma)
        share = var_d / (var_d + var_p)
        sigma = np.sqrt(var_d * var_p / (var_d + var_p))
        assert np.all(np.abs(moved - share * np.asarray(b.difference)) < 0.5 * sigma), p
    eff = blocks["accel_scale_misalignment"]
    full = np.asarray(alone.effects["accel_scale_misalignment"]["accel_matrix"]) - np.eye(3)
    theta = np.array([full[0, 0], full[1, 0], full[1, 1], full[2, 0], full[2, 1], full[2, 2]])
    assert np.all(np.abs(theta - eff.data_value) < 0.3 * np.asarray(eff.data_sigma))


def test_a_trend_prior_names_both_files(rig) -> None:
    new = rig["new"]
    priors = load_priors(rig["files"], new.imu.time_origin_ns)
    r = calibrate(new.imu, new.mocap, _options(priors=priors))
    assert r.priors is not None and not r.priors.conflicts
    assert r.priors.sources == tuple(str(f) for f in rig["files"])
    note = next(n for n in r.notes if n.startswith("priors used from"))
    assert all(str(f) in note for f in rig["files"])


def test_a_conflicting_prior_on_an_intrinsic_is_refused(rig) -> None:
    new, d = rig["new"], rig["dir"]
    data = yaml.safe_load(rig["files"][1].read_text())
    data["effects"]["accel_scale_misalignment"]["accel_matrix"][1][1] += 0.02  # y scale 2 %
    bad = d / "bad_intrinsics.yaml"
    bad.write_text(yaml.safe_dump(data))
    priors = load_priors([bad], new.imu.time_origin_ns)
    with pytest.raises(InputError) as err:
        calibrate(new.imu, new.mocap, _options(priors=priors))
    line = str(err.value)
    assert "\n" not in line
    for word in (str(bad), "accel_scale_misalignment", "accel_matrix[1,1]", "--trust-prior"):
        assert word in line, line


# --- batch: a history of another rig ----------------------------------------------------------

def test_a_batch_session_with_a_conflicting_history_fails_alone(cli_session, tmp_path,
                                                                 capsys) -> None:
    d, _ = cli_session
    other = simulate_flight(SimConfig(seed=8, duration=30.0))  # another rig, same imu_id
    write_mav0(tmp_path / "other", other.imu, other.mocap)
    (tmp_path / "m.yaml").write_text(
        "sessions:\n"
        f"  - {{id: first, imu_id: a, date: 2024-03-01, mav0: {d / 's'}}}\n"
        f"  - {{id: second, imu_id: a, date: 2024-03-08, mav0: {tmp_path / 'other'}}}\n")
    out = tmp_path / "out"
    code, stdout, err = _cli(["batch", str(tmp_path / "m.yaml"), "--out", str(out),
                              "--workers", "1", "--prior-from-history", "--quiet"], capsys)
    assert code == 1, err
    assert "Traceback" not in err
    status = {s["id"]: s for s in yaml.safe_load((out / "batch.yaml").read_text())["sessions"]}
    assert status["first"]["status"] == "ok" and status["second"]["status"] == "failed"
    line = status["second"]["error"]
    assert "\n" not in line
    for word in (str(out / "first" / "calib.yaml"), "as a --prior",
                 "from what this session's data say", "--trust-prior"):
        assert word in line, line
    assert f"second: {line}" in stdout  # the batch's summary shows the same line
    assert not (out / "second" / "calib.yaml").exists()
