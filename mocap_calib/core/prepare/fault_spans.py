"""The faulty IMU spans of a calibration session left out.

Dead sensors are refused and frozen mocap is removed when the session is prepared
(:func:`mocap_calib.core.prepare.session.prepare`, with
:mod:`mocap_calib.core.prepare.fault_detection`).
Saturated or frozen IMU samples cannot simply be dropped (the preintegration needs every sample
between two poses), so once the clock offset is known the mocap poses around them are removed:
no factor then spans them. How much was left out goes into the notes; a session that would lose
more than :data:`MAX_LEFT_OUT` of its poses is refused.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mocap_calib.core.model.rest import runs
from mocap_calib.core.prepare.session import PreparedSession
from mocap_calib.errors import ObservabilityError

#: Largest fraction of the mocap poses that may be left out around IMU faults.
MAX_LEFT_OUT = 0.5


def leave_out_imu_faults(s: PreparedSession, delta: float) -> tuple[PreparedSession, list[str]]:
    """Remove the mocap poses around saturated or frozen IMU samples (at ``tau = u + delta``).

    Returns:
        The session without those poses, and a note saying what was left out.

    Raises:
        ObservabilityError: more than :data:`MAX_LEFT_OUT` of the poses would go.
    """
    f = s.imu_faults
    if f is None or not f.any:
        return s, []
    spans = runs(f.bad, 1)
    # The preintegration interpolates with the samples' neighbours: two more on each side,
    # and a mocap step around so no interval between kept poses reaches a faulty sample.
    n = len(s.u)
    lo = s.u[np.clip(spans[:, 0] - 2, 0, n - 1)] + delta - 1.5 / s.mocap_rate
    hi = s.u[np.clip(spans[:, 1] + 2, 0, n - 1)] + delta + 1.5 / s.mocap_rate
    k = np.searchsorted(lo, s.tau, side="right") - 1
    drop = (k >= 0) & (s.tau <= hi[np.clip(k, 0, None)])
    fraction = float(drop.mean())
    what = "; ".join(f.what)
    if fraction > MAX_LEFT_OUT:
        raise ObservabilityError(
            f"the IMU is faulty in too much of the session ({what}): {100 * fraction:.0f} % of "
            "it would have to be left out; record with a larger sensor range or gentler motion")
    keep = ~drop
    out = replace(s, tau=s.tau[keep], R_WM=s.R_WM[keep], p_WM=s.p_WM[keep],
                  removed_tau=np.sort(np.concatenate([s.removed_tau, s.tau[drop]])))
    seconds = float(np.sum(np.diff(s.tau)[drop[1:]])) if len(s.tau) > 1 else 0.0
    return out, [f"left out {seconds:.2f} s ({100 * fraction:.1f} %) of the session around "
                 f"faulty IMU samples: {what}"]
