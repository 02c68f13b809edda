"""Multi-position IMU calibration without external equipment (Tedaldi, Pretto, Menegatti,
"A robust and easy to implement method for IMU calibration without external equipments",
ICRA 2014; the imu_tk implementation).

The session is an initial static period (``T_init``), then 36-50 static orientations of a few
seconds each joined by short rotations. The calibration runs in three steps:

1. *Static detector* (:mod:`.detector`): the magnitude ``|var_w(a)|^2`` of the per-axis accel
   variance over a centred window ``t_w`` is compared with ``k |var_init(a)|^2``, the same
   magnitude over the initial static period. ``k`` is scanned (2..10) and chosen by the
   accelerometer calibration residual, so no threshold has to be tuned.
2. *Accelerometer* (:mod:`.fit`): 9 parameters (lower-triangular ``M_a``: 3 scales, 3
   misalignments; bias ``b_a``) minimise ``sum_i (g^2 - |h_i|^2)^2`` with
   ``h_i = M_a^-1 (mean_i(a_m) - b_a)`` over the static intervals, by Levenberg-Marquardt.
3. *Gyroscope* (:mod:`.fit`): ``b_g`` is the mean gyro over the initial static period; ``M_g``
   (9 entries) makes the RK4 quaternion integration (:mod:`mocap_calib.core.model.preint`) of
   ``M_g^-1 (w_m - b_g)`` between consecutive static intervals carry the calibrated gravity
   direction of one interval onto that of the next.

The model is the measurement form of ``docs/conventions.md``: ``a_m = M_a f + b_a``,
``w_m = M_g w + b_g``. The IMU frame is the accelerometer's orthogonalised frame, hence ``M_a``
lower-triangular. Priors from earlier results (:mod:`.prior`) enter as weighted rows; the
result (:mod:`.result`) is a versioned ``intrinsics`` file; :mod:`.calibrate` orchestrates.

Two deliberate departures from imu_tk, both small: residuals are whitened by the noise of each
interval mean (measured inside the interval), and ``k`` is chosen by the *reduced* chi-square
(imu_tk uses the total cost, which favours thresholds that find fewer intervals); among
thresholds whose reduced chi-square is statistically indistinguishable from the best, the one
that finds the most intervals wins.
"""

from mocap_calib.core.intrinsics.multipos.calibrate import calibrate_multipos
from mocap_calib.core.intrinsics.multipos.detector import detect_static_intervals
from mocap_calib.core.intrinsics.multipos.params import PARAMETERS, POOR_SIGMA
from mocap_calib.core.intrinsics.multipos.prior import MultiposPrior
from mocap_calib.core.intrinsics.multipos.result import MultiposResult

__all__ = ["PARAMETERS", "POOR_SIGMA", "MultiposPrior", "MultiposResult", "calibrate_multipos",
           "detect_static_intervals"]
