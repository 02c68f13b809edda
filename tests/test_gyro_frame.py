"""The effects-shown refit compares R_MI in the gyro's frame when it adds a gyro matrix: the
frame is the rotation of the matrix's polar decomposition (analytic cases)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from mocap_calib.core.model import so3
from mocap_calib.core.model.effects import EFFECTS
from mocap_calib.core.uncertainty.sensitivity import gyro_frame

GYRO = [e for e in EFFECTS.values() if e.acts_on == "w" and e.about_identity][0]


def test_a_rotated_gyro_gives_its_rotation() -> None:
    R = so3.exp(np.radians([0.3, -0.5, 2.0]))
    theta = GYRO.theta_from_report(R)
    assert np.allclose(gyro_frame(SimpleNamespace(effects={GYRO.name: theta})), R, atol=1e-12)


def test_scale_alone_is_no_rotation() -> None:
    M = np.diag([1.01, 0.99, 1.02])  # symmetric: scale only
    theta = GYRO.theta_from_report(M)
    assert np.allclose(gyro_frame(SimpleNamespace(effects={GYRO.name: theta})), np.eye(3))


def test_rotation_times_scale_keeps_the_rotation() -> None:
    R = so3.exp(np.radians([1.0, 0.0, -1.5]))
    S = np.array([[1.02, 0.003, 0.0], [0.003, 0.99, 0.001], [0.0, 0.001, 1.01]])
    theta = GYRO.theta_from_report(R @ S)
    assert np.allclose(gyro_frame(SimpleNamespace(effects={GYRO.name: theta})), R, atol=1e-12)


def test_no_gyro_matrix_is_identity() -> None:
    assert np.allclose(gyro_frame(SimpleNamespace(effects={})), np.eye(3))
