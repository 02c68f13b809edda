"""The text report prints numbers as numbers, whatever type the analysis kept them in."""

from __future__ import annotations

import numpy as np

from mocap_calib.report.text import unexplained_lines


def test_unexplained_signature_prints_plain_numbers() -> None:
    sig = {"ratio_per_axis": [np.float64(4.1226), np.float64(1.5), np.float64(0.9)],
           "axes_over_floor": ["x"], "band_most_over_floor": "0.1-2 Hz",
           "rms_per_time_segment": np.array([1.2, 0.9, 0.8]), "correlation": {}}
    u = {"why": ["the gyro residual is 4.12 x the noise floor"], "gyro": sig, "accel": sig,
         "clock_offset_per_segment": {"t_d_ms": [np.float64(4.0), np.float64(4.2)],
                                      "slope_ppm": np.float64(12.5),
                                      "largest_jump_sigmas": np.float64(2.0)}}
    text = "\n".join(unexplained_lines(u))
    assert "np.float64" not in text and "array(" not in text, text
    assert "[4.12, 1.5, 0.9]" in text and "[4, 4.2]" in text, text
