"""The sensitivity's shifts count only moves beyond chance (analytic cases)."""

from __future__ import annotations

import numpy as np

from mocap_calib.core.model.parameters import TRANSLATION
from mocap_calib.core.uncertainty.sensitivity import (
    SIGNIFICANT,
    Sensitivity,
    _beyond_chance,
)


def _one(d: float, var_alt: float, var: float) -> tuple[float, float]:
    cov_alt = {TRANSLATION.name: np.diag([var_alt] * 3)}
    cov = {TRANSLATION.name: np.diag([var] * 3)}
    shift, raw = _beyond_chance({TRANSLATION: np.array([d, -d, 0.0])}, cov_alt, cov)
    assert raw[TRANSLATION][1] == abs(d) and shift[TRANSLATION][2] == 0.0
    return float(shift[TRANSLATION][0]), float(raw[TRANSLATION][0])


def test_a_move_within_chance_adds_nothing() -> None:
    # chance variance |1.0 - 0.5| = 0.5; a move of 1.0 is 1.4 chance sigmas
    assert SIGNIFICANT == 4.0
    assert _one(1.0, 1.0, 0.5) == (0.0, 1.0)


def test_a_significant_move_adds_its_excess_over_chance() -> None:
    # a move of 2.0 is 2.8 chance sigmas: the excess sqrt(4 - 0.5)
    shift, raw = _one(2.0, 1.0, 0.5)
    assert np.isclose(shift, np.sqrt(3.5)) and raw == 2.0


def test_without_covariances_every_move_counts() -> None:
    shift, raw = _beyond_chance({TRANSLATION: np.array([0.3, 0.0, 0.1])}, {}, {})
    assert np.allclose(shift[TRANSLATION], [0.3, 0.0, 0.1])


def test_the_floor_takes_only_moves_beyond_chance() -> None:
    s = Sensitivity(shift={"x3": {TRANSLATION: np.array([0.0, 1.5, 0.0])},
                           "x0.333": {TRANSLATION: np.array([0.0, 0.0, 0.2])}},
                    raw={"x3": {TRANSLATION: np.array([1.0, 2.0, 0.5])},
                         "x0.333": {TRANSLATION: np.array([3.0, 0.1, 0.4])}})
    assert np.allclose(s.largest_move(TRANSLATION), [0.0, 2.0, 0.4])
    assert np.allclose(s.systematic(TRANSLATION), [0.0, 1.5, 0.2])
