"""Result and noise YAML files: exact round trips, the conventions' keys, and one-line
InputErrors for newer, malformed or incomplete files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from mocap_calib.core.model.parameters import (
    ACCEL_BIAS,
    GRAVITY_DIRECTION,
    GYRO_BIAS,
    ROTATION,
    TIME_OFFSET,
    TRANSLATION,
)
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.result.calibration import RESULT_VERSION, CalibrationResult
from mocap_calib.core.result.estimate import Estimate
from mocap_calib.core.result.sections import SolverFigures
from mocap_calib.core.stages.figures import StageStats
from mocap_calib.errors import InputError
from mocap_calib.io.yaml_io import load_noise, load_result, save_result

ARRAY_FIELDS = ("gyro_bias", "accel_bias", "rotation_wxyz", "translation", "gravity_in_mocap",
                "sigma_gyro_bias", "sigma_accel_bias", "sigma_rotation", "sigma_translation",
                "sigma_gravity")


def make_result() -> CalibrationResult:
    q = np.array([0.7, -0.1, 0.6, 0.2])
    g = np.array([0.03, -0.02, -1.0])
    values = {GYRO_BIAS: ([1.234e-3, -2.5e-4, 7.0e-5], [1e-5, 2e-5, 3e-5]),
              ACCEL_BIAS: ([0.0512, -0.113, 0.0271], [1e-3, 2e-3, 3e-3]),
              ROTATION: (q / np.linalg.norm(q), [1e-3, 2e-3, 3e-3]),
              TRANSLATION: ([0.0123, -0.0456, 0.0789], [1e-4, 2e-4, 3e-4]),
              GRAVITY_DIRECTION: (g / np.linalg.norm(g), [4e-4, 5e-4]),
              TIME_OFFSET: (None, None)}  # unobservable in this session
    return CalibrationResult(
        estimates={p: Estimate.of(p, v, s) for p, (v, s) in values.items()},
        gravity_magnitude=9.80665,
        model="base+time_offset+gyro_scale_misalignment+gyro_g_sensitivity+gyro_bias_drift",
        effects={
            "gyro_scale_misalignment": {
                "gyro_matrix": [[1.001, 0.002, -0.003], [0.004, 0.998, 0.005],
                                [-0.006, 0.007, 1.0025]],
                "sigma": [[1e-4, 2e-4, 3e-4], [4e-4, 5e-4, 6e-4], [7e-4, 8e-4, 9e-4]]},
            "gyro_g_sensitivity": {"g_sensitivity": None},
            "gyro_bias_drift": {"gyro_bias_rate": [1e-6, -2e-6, 3e-6], "sigma": [1e-7] * 3},
            "time_offset": {"time_offset": None},
        },
        unobservable={"time_offset": "the session has no motion to align the clocks",
                      "g_sensitivity": "too little specific-force variation"},
        stages=(StageStats("attitude", "rad/s", [1e-3, 2e-3, 3e-3], [1e-4, 2e-4, 3e-4], 120,
                           121, 2, 7, 0.5, 1.01, rms_after_inliers=[9e-5, 1e-4, 2e-4]),),
        solver=SolverFigures(stage={"iterations": 12, "converged": True, "robust": "huber"}),
        noise=NoiseModel(1e-4, 2e-5, 3e-3, 4e-4, 5e-4, 6e-4),
        notes=("first note", "second: with a colon"),
        session={"imu_samples": 1000, "imu_file": "mav0/imu0/data.csv"},
    )


def assert_same(a: CalibrationResult, b: CalibrationResult) -> None:
    for name in ARRAY_FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        if x is None:
            assert y is None, name
        else:
            assert isinstance(y, np.ndarray), name
            np.testing.assert_array_equal(x, y, err_msg=name)
    for name in ("time_offset", "sigma_time_offset", "gravity_magnitude", "model", "effects",
                 "unobservable", "stages", "solver", "noise", "notes", "session", "version"):
        assert getattr(a, name) == getattr(b, name), name


def test_result_round_trip_is_exact(tmp_path: Path) -> None:
    res = make_result()
    path = save_result(tmp_path / "sub" / "calib.yaml", res)
    back = load_result(path)
    assert_same(res, back)
    # Saving what was loaded writes the same bytes.
    again = save_result(tmp_path / "again.yaml", back)
    assert again.read_bytes() == path.read_bytes()


def test_result_file_has_conventions_keys(tmp_path: Path) -> None:
    res = make_result()
    data = yaml.safe_load(save_result(tmp_path / "calib.yaml", res).read_text())
    assert list(data)[:8] == ["kind", "version", "gyro_bias", "accel_bias", "T_marker_imu",
                              "gravity_in_mocap",
                              "time_offset", "sigma"]
    assert set(data["T_marker_imu"]) == {"rotation_wxyz", "translation"}
    assert set(data["sigma"]) == {"gyro_bias", "accel_bias", "rotation", "translation",
                                  "gravity_in_mocap", "time_offset"}
    assert data["gyro_bias"] == [1.234e-3, -2.5e-4, 7.0e-5]
    assert data["T_marker_imu"]["translation"] == [0.0123, -0.0456, 0.0789]
    assert data["sigma"]["gravity_in_mocap"] == [4e-4, 5e-4]
    # An unobservable parameter is null with its reason, never a number.
    assert data["time_offset"] is None
    assert data["sigma"]["time_offset"] is None
    assert "time_offset" in data["unobservable"]
    assert data["version"] == RESULT_VERSION
    assert data["effects"]["gyro_scale_misalignment"]["gyro_matrix"][2] == [-0.006, 0.007, 1.0025]


def test_result_with_all_parameters_unobservable_round_trips(tmp_path: Path) -> None:
    res = CalibrationResult()
    back = load_result(save_result(tmp_path / "r.yaml", res))
    assert_same(res, back)


def write(tmp_path: Path, text: str, name: str = "r.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


MINIMAL = """gyro_bias: [0.001, 0.002, 0.003]
accel_bias: [0.01, 0.02, 0.03]
T_marker_imu:
  rotation_wxyz: [1.0, 0.0, 0.0, 0.0]
  translation: [0.1, 0.2, 0.3]
gravity_in_mocap: [0.0, 0.0, -1.0]
time_offset: 0.004
"""


def test_minimal_hand_written_result_loads(tmp_path: Path) -> None:
    res = load_result(write(tmp_path, MINIMAL))
    np.testing.assert_array_equal(res.gyro_bias, [0.001, 0.002, 0.003])
    np.testing.assert_array_equal(res.translation, [0.1, 0.2, 0.3])
    assert res.time_offset == 0.004
    assert res.sigma_gyro_bias is None


def test_newer_version_is_rejected(tmp_path: Path) -> None:
    p = write(tmp_path, MINIMAL + f"version: {RESULT_VERSION + 1}\n")
    with pytest.raises(InputError) as err:
        load_result(p)
    msg = str(err.value)
    assert "newer" in msg and str(RESULT_VERSION + 1) in msg and str(p) in msg
    assert "\n" not in msg


def test_current_version_is_accepted(tmp_path: Path) -> None:
    assert load_result(write(tmp_path, MINIMAL + f"version: {RESULT_VERSION}\n")).version == \
        RESULT_VERSION


def test_malformed_yaml_names_the_line(tmp_path: Path) -> None:
    lines = MINIMAL.splitlines()
    lines.insert(4, "  broken: key: value")  # line 5 of the file
    p = write(tmp_path, "\n".join(lines) + "\n")
    with pytest.raises(InputError) as err:
        load_result(p)
    msg = str(err.value)
    assert "line 5" in msg and str(p) in msg and "YAML" in msg
    assert "\n" not in msg


def test_unclosed_bracket_is_input_error(tmp_path: Path) -> None:
    p = write(tmp_path, MINIMAL.replace("[0.01, 0.02, 0.03]", "[0.01, 0.02, 0.03"))
    with pytest.raises(InputError, match="line"):
        load_result(p)


@pytest.mark.parametrize("key", ["gyro_bias", "accel_bias", "T_marker_imu", "gravity_in_mocap"])
def test_missing_key_is_named(tmp_path: Path, key: str) -> None:
    data = yaml.safe_load(MINIMAL)
    del data[key]
    p = write(tmp_path, yaml.safe_dump(data))
    with pytest.raises(InputError, match=f"missing key '{key}'"):
        load_result(p)


@pytest.mark.parametrize("text", ["", "- 1\n- 2\n", "just a string\n"])
def test_not_a_mapping_is_input_error(tmp_path: Path, text: str) -> None:
    with pytest.raises(InputError, match="mapping"):
        load_result(write(tmp_path, text))


def test_missing_file_is_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        load_result(tmp_path / "nope.yaml")


@pytest.mark.parametrize("old,new", [
    ("gyro_bias: [0.001, 0.002, 0.003]", "gyro_bias: abc"),
    ("gyro_bias: [0.001, 0.002, 0.003]", "gyro_bias: {x: 1}"),
    ("time_offset: 0.004", "time_offset: soon"),
])
def test_malformed_values_are_input_error(tmp_path: Path, old: str, new: str) -> None:
    with pytest.raises(InputError, match="malformed"):
        load_result(write(tmp_path, MINIMAL.replace(old, new)))


@pytest.mark.parametrize("text", [
    pytest.param(MINIMAL + "version: two\n", id="version-not-integer"),
    pytest.param(MINIMAL.replace(
        "T_marker_imu:\n  rotation_wxyz: [1.0, 0.0, 0.0, 0.0]\n  translation: [0.1, 0.2, 0.3]\n",
        "T_marker_imu: 5\n"), id="T_marker_imu-not-mapping"),
    pytest.param(MINIMAL + "sigma: [1, 2]\n", id="sigma-not-mapping"),
    pytest.param(MINIMAL.replace("gyro_bias: [0.001, 0.002, 0.003]", "gyro_bias: [0.001, 0.002]"),
                 id="gyro_bias-wrong-length"),
])
def test_structurally_wrong_results_are_input_error(tmp_path: Path, text: str) -> None:
    with pytest.raises(InputError):
        load_result(write(tmp_path, text))


def test_truth_file_loads_as_result(tmp_path: Path) -> None:
    from mocap_calib.workflows.simulate import simulate_to_folder

    simulate_to_folder(tmp_path / "sim", seed=3, duration=3.0, effects=["time_offset=0.01"])
    truth_path = tmp_path / "sim" / "truth.yaml"
    truth = yaml.safe_load(truth_path.read_text())
    res = load_result(truth_path)
    np.testing.assert_array_equal(res.gyro_bias, truth["gyro_bias"])
    np.testing.assert_array_equal(res.rotation_wxyz, truth["T_marker_imu"]["rotation_wxyz"])
    assert res.time_offset == 0.01
    assert res.model == "base+time_offset"


# --- noise files -----------------------------------------------------------------------------

KALIBR_IMU_YAML = """#Accelerometers
accelerometer_noise_density: 1.86e-03   #Noise density (continuous-time)
accelerometer_random_walk:   4.33e-04   #Bias random walk

#Gyroscopes
gyroscope_noise_density:     1.87e-04   #Noise density (continuous-time)
gyroscope_random_walk:       2.66e-05   #Bias random walk

rostopic:                    /imu0      #the IMU ROS topic
update_rate:                 200.0      #Hz (for discretization of the values above)
"""

OTHER_BASE = NoiseModel(1.0, 2.0, 3.0, 4.0, 5.0, 6.0)


def test_load_noise_reads_kalibr_imu_yaml(tmp_path: Path) -> None:
    n = load_noise(write(tmp_path, KALIBR_IMU_YAML, "imu.yaml"), OTHER_BASE)
    assert n.accelerometer_noise_density == 1.86e-03
    assert n.accelerometer_random_walk == 4.33e-04
    assert n.gyroscope_noise_density == 1.87e-04
    assert n.gyroscope_random_walk == 2.66e-05
    # Keys the file does not have keep the base values.
    assert n.mocap_position_sigma == 5.0 and n.mocap_rotation_sigma == 6.0


def test_load_noise_reads_values_yaml_takes_as_strings(tmp_path: Path) -> None:
    """YAML 1.1 reads ``2e-3`` (no dot) as a string; it is still a number to the user."""
    text = ("gyroscope_noise_density: 2e-4\ngyroscope_random_walk: 3e-5\n"
            "accelerometer_noise_density: 2e-3\naccelerometer_random_walk: 4e-3\n")
    n = load_noise(write(tmp_path, text, "imu.yaml"), OTHER_BASE)
    assert (n.gyroscope_noise_density, n.gyroscope_random_walk, n.accelerometer_noise_density,
            n.accelerometer_random_walk) == (2e-4, 3e-5, 2e-3, 4e-3)


def test_load_noise_partial_file_keeps_base(tmp_path: Path) -> None:
    n = load_noise(write(tmp_path, "gyroscope_noise_density: 0.5\n"), OTHER_BASE)
    assert n == NoiseModel(0.5, 2.0, 3.0, 4.0, 5.0, 6.0)


def test_load_noise_reads_euroc_sensor_yaml(euroc_dir: Path) -> None:
    n = load_noise(euroc_dir / "mav0" / "imu0" / "sensor.yaml", OTHER_BASE)
    assert n.gyroscope_noise_density == 1.6968e-04
    assert n.gyroscope_random_walk == 1.9393e-05
    assert n.accelerometer_noise_density == 2.0000e-3
    assert n.accelerometer_random_walk == 3.0000e-3
    assert n.mocap_position_sigma == 5.0 and n.mocap_rotation_sigma == 6.0


@pytest.mark.parametrize("value,fragment", [
    ("-1.0e-4", "positive"),
    ("0.0", "positive"),
    (".nan", "positive"),
    ("abc", "number"),
    ("[1, 2]", "number"),
])
def test_load_noise_rejects_bad_values(tmp_path: Path, value: str, fragment: str) -> None:
    p = write(tmp_path, KALIBR_IMU_YAML.replace("1.87e-04", value), "imu.yaml")
    with pytest.raises(InputError) as err:
        load_noise(p)
    msg = str(err.value)
    assert fragment in msg and "gyroscope_noise_density" in msg and str(p) in msg


@pytest.mark.parametrize("text", ["rostopic: /imu0\nupdate_rate: 200.0\n",
                                  "mocap_position_sigma: 0.001\n"])
def test_load_noise_rejects_files_without_noise_keys(tmp_path: Path, text: str) -> None:
    with pytest.raises(InputError, match="no noise keys"):
        load_noise(write(tmp_path, text, "imu.yaml"))


def test_result_kind_and_version_are_checked() -> None:
    from mocap_calib.core.versioned import KindError

    d = make_result().to_dict()
    assert (d["kind"], d["version"]) == ("calibration", 1)
    assert CalibrationResult.from_dict(d).to_dict() == d
    with pytest.raises(KindError, match="newer"):
        CalibrationResult.from_dict({**d, "version": 99})
    with pytest.raises(KindError, match="diagnosis file"):
        CalibrationResult.from_dict({**d, "kind": "diagnosis"})


def test_other_kind_of_file_is_named(tmp_path: Path) -> None:
    p = tmp_path / "noise.yaml"
    p.write_text("kind: noise\nversion: 1\ngyroscope_noise_density: 1e-4\n")
    with pytest.raises(InputError, match="noise file, not a calibration file"):
        load_result(p)


def test_text_report_keeps_the_precision_of_a_huge_clock_offset() -> None:
    from mocap_calib.report.text import summary_table

    res = make_result()
    res = res.with_estimates({TIME_OFFSET: Estimate.of(TIME_OFFSET, -1_035_123.456789, 5e-5)})
    row = next(x for x in summary_table(res).splitlines() if x.startswith("time_offset"))
    assert "-1035123456.789" in row and "e+" not in row
