"""Physical ranges of the parameters: weak priors that keep every graph well posed.

A parameter whose posterior sigma is not well below its range was not determined by the data
and is reported as unobservable instead of as a number. Each effect's range is part of its
rung of the ladder (:data:`~mocap_calib.core.model.effects.EFFECTS`).
"""

from mocap_calib.core.model.effects import EFFECTS

#: Weak priors (1 sigma) that only regularise: a parameter whose posterior sigma is not well
#: below its prior sigma was not determined by the data.
RANGE_SIGMA: dict[str, float] = {
    "rotation": 0.5,  # rad
    "translation": 0.5,  # m
    "gravity": 0.3,  # rad
    "gyro_bias": 0.5,  # rad/s (first knot)
    "accel_bias": 2.0,  # m/s^2 (first knot)
    **{e.name: e.range_sigma for e in EFFECTS.values()},
}
#: Posterior/prior sigma ratio above which a parameter counts as not determined by the data.
UNOBSERVABLE_RATIO = 0.3
