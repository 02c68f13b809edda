"""The multi-position model's parameters and the limits its reports use."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

#: Parameters of the multi-position model, with their shapes.
PARAMETERS: dict[str, tuple[int, ...]] = {
    "accel_matrix": (3, 3),
    "accel_bias": (3,),
    "gyro_matrix": (3, 3),
    "gyro_bias": (3,),
}

#: Free entries of the lower-triangular ``M_a``.
LOWER = [(0, 0), (1, 0), (1, 1), (2, 0), (2, 1), (2, 2)]

#: 1-sigma above which a parameter is reported as poorly determined.
POOR_SIGMA: dict[str, float] = {
    "scale": 1e-3,  # diagonal of M_a, M_g (relative)
    "misalignment": float(np.radians(0.05)),  # off-diagonal of M_a, M_g (rad)
    "accel_bias": 5e-3,  # m/s^2
    "gyro_bias": 1e-4,  # rad/s
}

#: Condition number (of the column-normalised normal matrix) above which a fit is flagged.
POOR_CONDITION = 1e8

#: Two static intervals count as distinct orientations if their gravity directions differ by
#: more than this angle.
DISTINCT_DEG = 10.0


def option(names: Mapping[str, str] | None, key: str) -> str:
    """How the caller spells option ``key`` in messages (a CLI passes ``--init-static`` for
    ``init_static_s``); the keyword itself by default."""
    return (names or {}).get(key, key)


def option_value(names: Mapping[str, str] | None, key: str, value: object) -> str:
    """``key=value`` for keywords, ``--option value`` for command-line options."""
    name = option(names, key)
    return f"{name} {value}" if name.startswith("-") else f"{name}={value}"
