"""Physical constants, units and data rules: each in one place, used by every layer.

The gap rule decides what every reader and every command does with a stream whose samples do
not come at a steady rate (logger buffer overruns, dropped USB/serial packets, occlusions):

- a step up to :data:`GAP_FACTOR` median steps is no gap (jitter, one dropped sample): the
  cubic interpolant of the samples bridges it;
- a longer step is a gap. An IMU gap of up to :data:`IMU_BRIDGE_MAX_S` is *bridged*: nothing
  is integrated across it (windows and keyframe intervals end at it) and the bias random walk
  runs on over it. A longer IMU gap *splits* the session into segments that share every
  calibration quantity; the biases keep their random walk across the split (the sensor was on,
  only the log stopped), with the variance the gap's duration gives it;
- gaps within the first :data:`IMU_TRIM_START_S` of the log (logger start) trim the samples
  before them;
- a session whose gaps cover more than :data:`IMU_MAX_GAP_FRACTION` of it, or that keeps less
  than :data:`MIN_SEGMENT_S` of gap-free data, is refused; gap-free stretches shorter than
  :data:`MIN_SEGMENT_S` are left out.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

# ---------------------------------------------------------------- physical constants
#: The |g| a calibration assumes unless told (``--gravity``), m/s^2.
GRAVITY = 9.81
#: Standard gravity, m/s^2: the unit ``g`` of accelerometer logs.
STANDARD_GRAVITY = 9.80665

# ---------------------------------------------------------------- units
#: Position units of mocap files, in metres.
POSITION_UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001}
#: Gyro units, in rad/s.
GYRO_UNITS: dict[str, float] = {"rad/s": 1.0, "deg/s": float(np.pi / 180.0)}
#: Accelerometer units, in m/s^2.
ACCEL_UNITS: dict[str, float] = {"m/s^2": 1.0, "g": STANDARD_GRAVITY}
#: Time-stamp units, in nanoseconds.
TIME_UNITS_NS: dict[str, int] = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}

# ---------------------------------------------------------------- the gap rule
#: A step longer than this many median steps is a gap (either stream).
GAP_FACTOR = 3.0
#: IMU gaps up to this long (s) are bridged; longer ones split the session into segments.
IMU_BRIDGE_MAX_S = 0.5
#: Gaps within this long (s) of the IMU log's first sample trim the samples before them.
IMU_TRIM_START_S = 1.0
#: Gaps covering more than this fraction of the session: refused.
IMU_MAX_GAP_FRACTION = 0.5
#: Gap-free stretches shorter than this (s) are left out; a session with none longer, refused.
MIN_SEGMENT_S = 2.0
#: Shortest session (s) a calibration accepts (also what --start/--end must leave).
MIN_SESSION_S = 10.0


def gap_threshold(t: Array, floor: float = 0.0) -> float:
    """Longest step (s) of the time series ``t`` that is not a gap (see :data:`GAP_FACTOR`)."""
    return max(GAP_FACTOR * float(np.median(np.diff(t))), floor)
