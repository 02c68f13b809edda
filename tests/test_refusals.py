"""Refuse what cannot be right and name the mistake.

The corpus (``tests/refusal_corpus.py``): a clean 30 s simulated session corrupted one way at a
time, run through the CLI as a user would. No case may exit 0 with a wrong answer (numbers are
checked against the simulator's truth, within 5 of the tool's own sigmas and within what would
be of any use), none may exit 70, and every refusal must be one line naming the mistake. The
table of cases and verdicts is ``docs/refusals.md`` (``scripts/refusal_table.py``).
"""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest
from conftest import shared_data
from refusal_corpus import Case, clean, run_case, session
from refusal_more import ALL_CASES as CASES

from mocap_calib.cli.main import _is_indeterminate
from mocap_calib.core.clock.conventions import check_conventions
from mocap_calib.core.gtsam_tools import marginals
from mocap_calib.core.model.types import ImuSamples
from mocap_calib.core.options import CalibrationOptions
from mocap_calib.core.pipeline.calibrate import calibrate
from mocap_calib.core.prepare.fault_detection import frozen, imu_faults
from mocap_calib.core.prepare.session import prepare
from mocap_calib.errors import InputError, ObservabilityError


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_corpus_case(case: Case, tmp_path: Path) -> None:
    v = run_case(case, tmp_path / case.name)
    assert v.ok, f"{case.what}: " + "; ".join(v.problems)


def test_gyro_in_deg_per_s_is_named_by_the_convention_check() -> None:
    """A slow session's gyro in deg/s can pass the reader's magnitude check; the calibration
    must still name the unit instead of fitting a gyro 57 times too fast."""
    s = session(motion="slow")
    imu = ImuSamples(s.imu.t, np.degrees(s.imu.gyro), s.imu.accel, s.imu.time_origin_ns)
    with pytest.raises(InputError, match="--gyro-unit deg/s"):
        calibrate(imu, s.mocap, CalibrationOptions(segments=0, sensitivity=False))


def test_gtsam_indeterminate_system_is_one_line() -> None:
    graph = gtsam.NonlinearFactorGraph()
    k1, k2 = gtsam.symbol("x", 1), gtsam.symbol("x", 2)
    graph.add(gtsam.BetweenFactorPose2(k1, k2, gtsam.Pose2(),
                                       gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
    values = gtsam.Values()
    values.insert(k1, gtsam.Pose2())
    values.insert(k2, gtsam.Pose2())
    with pytest.raises(ObservabilityError) as err:
        marginals(graph, values)
    assert "\n" not in str(err.value) and "indeterminate" in str(err.value)
    try:
        gtsam.Marginals(graph, values)
    except RuntimeError as raw:  # what the CLI's last line of defence recognises
        assert _is_indeterminate(raw)


def test_streams_in_error_are_not_explained_by_chance() -> None:
    """The mismatch verdict compares with offsets known to be wrong: a matching pair passes
    (returns its fit), a pair from two recordings is refused."""
    s = prepare(clean().imu, clean().mocap)
    fit = check_conventions(s, [0.0])
    assert fit is not None and abs(fit.t_d) < 0.01 and fit.rotation_ratio < 0.05
    other = prepare(clean().imu, session(seed=8).mocap)
    with pytest.raises(ObservabilityError, match="no better than chance"):
        check_conventions(other, [0.0])


@pytest.mark.slow  # full calibrations: in the whole suite, not the quick subset
@pytest.mark.parametrize("name", ["euroc", "broad21"])
def test_real_sessions_pass_the_checks(name: str) -> None:
    """Real recordings read the right way: the convention check finds the data as given
    (and the clock offset the calibration finds, within 10 ms), and the fault screen leaves
    nothing out (quantised, duplicated samples are not frozen, peaks are not clipping)."""
    from mocap_calib.workflows.session import InputSpec, load_session

    if name == "euroc":
        spec = InputSpec(mav0=(shared_data("euroc_V2_03_difficult", "mav0").parent,))
        t_d = -0.197  # this session's coarse offset (-200.3 ms fine, README's real-data section)
    else:
        p = shared_data("broad_21_undisturbed_fast_combined", "data.csv")
        spec = InputSpec(imu=p, mocap=p, columns="broad")
        t_d = -0.003
    loaded = load_session(spec)
    f = imu_faults(loaded.imu.gyro, loaded.imu.accel, loaded.imu.rate_hz)
    assert not f.any, f.what
    m = loaded.mocap
    assert not frozen(np.hstack([m.quat_wxyz, m.position]), m.rate_hz, 3, 0.03).any()
    fit = check_conventions(prepare(loaded.imu, loaded.mocap), [t_d])
    assert fit is not None and abs(fit.t_d - t_d) < 0.01
