"""Physical ranges of the parameters: weak priors that keep every graph well posed.

A parameter whose posterior sigma is not well below its range was not determined by the data
and is reported as unobservable instead of as a number.
"""

#: Weak priors (1 sigma) that only regularise: a parameter whose posterior sigma is not well
#: below its prior sigma was not determined by the data.
RANGE_SIGMA: dict[str, float] = {
    "rotation": 0.5,  # rad
    "translation": 0.5,  # m
    "gravity": 0.3,  # rad
    "time_offset": 0.05,  # s
    "gravity_magnitude": 0.5,  # m/s^2
    "gyro_scale_misalignment": 0.05,
    "accel_scale_misalignment": 0.05,
    "gyro_g_sensitivity": 0.01,  # rad/s per m/s^2
    "gyro_bias_drift": 1e-3,  # rad/s^2
    "accel_bias_drift": 0.05,  # m/s^3
    "gyro_bias": 0.5,  # rad/s (first knot)
    "accel_bias": 2.0,  # m/s^2 (first knot)
}
#: Posterior/prior sigma ratio above which a parameter counts as not determined by the data.
UNOBSERVABLE_RATIO = 0.3
