"""The calibrated model's state and the trace a calibration leaves for inspection.

:class:`ModelState` is everything needed to predict the IMU from the mocap (calibration plus the
bias trajectory); :class:`CalibrationTrace` is what the solver used (prepared session, noise
model, windows, robust weights), typed, for the diagnosis, reports and recordings.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.effects import Model
from mocap_calib.core.model.types import NoiseModel

if TYPE_CHECKING:
    from mocap_calib.core.clock.search import ClockSearch
    from mocap_calib.core.position.engine import Windows
    from mocap_calib.core.position.stage import PositionResult
    from mocap_calib.core.prepare.session import PreparedSession

Array = NDArray[np.float64]


@dataclass
class ModelState:
    """Everything needed to predict IMU samples: calibration plus the bias trajectory.

    Attributes:
        R_MI, p_MI: IMU pose in the marker frame.
        g_W: gravity vector in the mocap world (m/s^2).
        delta: mocap time minus IMU time (relative clocks, see :mod:`session`).
        model: active effects; effects: their IMU-side parameters.
        bias_t: (K,) mocap times of the bias knots; bias: (K, 6) gyro and accel bias there.
        t_mid: IMU-clock middle of the session (drift terms).
        bias_sigma: (K, 6) 1-sigma of the knots (their estimation error is part of the floor).
    """

    R_MI: Array
    p_MI: Array
    g_W: Array
    delta: float
    model: Model
    effects: dict[str, Array]
    bias_t: Array
    bias: Array
    t_mid: float
    bias_sigma: Array | None = None

    @classmethod
    def from_position(cls, pos, model: Model, t_mid: float, take: int = 0) -> ModelState:
        """The state a position-stage result (``stage_position.PositionResult``) describes
        for its take ``take`` (the shared parameters with that take's clock and biases)."""
        tk = pos.takes[take]
        return cls(R_MI=pos.R_MI, p_MI=pos.p_MI, g_W=pos.g_mag * pos.g_dir, delta=tk.delta,
                   model=model, effects=pos.effects, bias_t=tk.windows.start.copy(),
                   bias=tk.knots.copy(), t_mid=t_mid, bias_sigma=tk.knot_sigma.copy())

    def bias_at(self, tau: Array) -> Array:
        """(n, 6) bias at mocap times ``tau`` (linear between knots, constant outside)."""
        if len(self.bias_t) == 1:
            return np.broadcast_to(self.bias[0], (len(tau), 6)).copy()
        return np.stack([np.interp(tau, self.bias_t, self.bias[:, i]) for i in range(6)], axis=1)


@dataclass
class CalibrationTrace:
    """What the solver worked with, for the diagnosis, reports and recordings (not serialised).

    Attributes:
        session: the prepared session (relative clocks, spikes removed).
        model_state: the calibrated model with the bias trajectory.
        noise_used: the noise model at the solution (mocap levels re-estimated).
        windows: the position-stage windows.
        weights: (W, m+1) robust weights of the window samples at the solution.
        clock: the coarse clock search with its correlation curve.
    """

    session: PreparedSession
    model_state: ModelState
    noise_used: NoiseModel
    windows: Windows
    weights: Array
    clock: ClockSearch | None = None  # the coarse clock search (None: offset given)
    position: PositionResult | None = None  # the position stage's own result
