"""The result of a multi-position calibration and its versioned plain-data form (kind
``intrinsics``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.intrinsics.multipos.params import PARAMETERS
from mocap_calib.core.model.versioned import check_kind, header

Array = NDArray[np.float64]

KIND = "intrinsics"
VERSION = 1
#: Keys that identify an intrinsics file written before ``kind`` existed.
LEGACY_KEYS = ("accel_matrix", "gyro_matrix")


def _array(d: Mapping[str, Any], key: str, shape: tuple[int, ...], where: str = "") -> Array:
    """A float array of ``shape`` from ``d[key]``; ValueError naming the key otherwise."""
    if key not in d or d[key] is None:
        raise ValueError(f"no '{where}{key}'")
    try:
        a = np.asarray(d[key], dtype=float)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != shape:
        raise ValueError(f"'{where}{key}' must be {shape} numbers")
    return a


@dataclass(frozen=True)
class MultiposResult:
    """Intrinsics from a multi-position session, in the measurement model's form.

    Attributes:
        accel_matrix: ``M_a`` (3x3, lower-triangular) in ``a_m = M_a f + b_a``.
        accel_bias: ``b_a`` in m/s^2.
        gyro_matrix: ``M_g`` (3x3) in ``w_m = M_g w + b_g``.
        gyro_bias: ``b_g`` in rad/s (mean gyro over the initial static period).
        accel_matrix_sigma: 1-sigma of ``M_a`` (0 above the diagonal: not a parameter).
        accel_bias_sigma: 1-sigma of ``b_a``.
        gyro_matrix_sigma: 1-sigma of ``M_g``.
        gyro_bias_sigma: 1-sigma of ``b_g``.
        accel_residual_rms: RMS of ``|h_i| - g`` over the static intervals, m/s^2.
        gyro_residual_rms: RMS over the rotations of the gravity-direction error, rad.
        threshold_multiple: the chosen static-detector multiple ``k``.
        n_static_intervals: static intervals used (the initial period included).
        n_distinct_orientations: of those, gravity directions more than 10 deg apart.
        static_intervals: (n, 2) start and end time (s, IMU clock) of each interval.
        poorly_determined: parameters whose sigma is large (see ``POOR_SIGMA``), or
            ``"<sensor> fit ill-conditioned ..."``.
        accel_condition: condition number of the accel fit's normal matrix (columns
            normalised).
        gyro_condition: same for the gyro fit.
        accel_chi2: reduced chi-square of the accel fit (1 when the residuals are at the
            noise level of the interval means).
        gyro_chi2: reduced chi-square of the gyro fit.
        gravity: ``|g|`` assumed, m/s^2.
        session_time_ns: stamp of the session's first sample (for trends over sessions).
        prior_source: what the prior came from, or None without one.
        threshold_scan: per tried ``k``: ``{k, n_intervals, chi2}`` (chi2 None if unusable).
    """

    accel_matrix: Array
    accel_bias: Array
    gyro_matrix: Array
    gyro_bias: Array
    accel_matrix_sigma: Array
    accel_bias_sigma: Array
    gyro_matrix_sigma: Array
    gyro_bias_sigma: Array
    accel_residual_rms: float
    gyro_residual_rms: float
    threshold_multiple: float
    n_static_intervals: int
    n_distinct_orientations: int
    static_intervals: Array
    poorly_determined: list[str]
    accel_condition: float
    gyro_condition: float
    accel_chi2: float
    gyro_chi2: float
    gravity: float
    session_time_ns: int
    prior_source: str | None = None
    threshold_scan: list[dict[str, Any]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """``kind``/``version``, the intrinsics keys of ``docs/conventions.md``, then
        ``sigma``, ``residuals`` and ``diagnostics`` (plain Python types, ready for YAML)."""
        return {
            **header(KIND, VERSION),
            "accel_matrix": self.accel_matrix.tolist(),
            "accel_bias": self.accel_bias.tolist(),
            "gyro_matrix": self.gyro_matrix.tolist(),
            "gyro_bias": self.gyro_bias.tolist(),
            "sigma": {
                "accel_matrix": self.accel_matrix_sigma.tolist(),
                "accel_bias": self.accel_bias_sigma.tolist(),
                "gyro_matrix": self.gyro_matrix_sigma.tolist(),
                "gyro_bias": self.gyro_bias_sigma.tolist(),
            },
            "residuals": {
                "accel_rms_mps2": float(self.accel_residual_rms),
                "gyro_rms_rad": float(self.gyro_residual_rms),
                "accel_chi2": float(self.accel_chi2),
                "gyro_chi2": float(self.gyro_chi2),
            },
            "diagnostics": {
                "threshold_multiple": float(self.threshold_multiple),
                "n_static_intervals": int(self.n_static_intervals),
                "n_distinct_orientations": int(self.n_distinct_orientations),
                "static_intervals_s": self.static_intervals.tolist(),
                "poorly_determined": list(self.poorly_determined),
                "accel_condition_number": float(self.accel_condition),
                "gyro_condition_number": float(self.gyro_condition),
                "gravity_magnitude": float(self.gravity),
                "session_time_ns": int(self.session_time_ns),
                "prior": self.prior_source,
                "threshold_scan": list(self.threshold_scan),
            },
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> MultiposResult:
        """Inverse of :meth:`to_dict` (also reads files written before ``kind`` existed).

        Raises:
            KindError: another kind of file, or a newer version.
            ValueError: a missing or malformed entry (the message names it).
        """
        check_kind(dict(d), KIND, VERSION, legacy=LEGACY_KEYS)
        sigma = d.get("sigma")
        if not isinstance(sigma, Mapping):
            raise ValueError("no 'sigma: {...}' with the 1-sigma of every parameter")
        values = {k: _array(d, k, s) for k, s in PARAMETERS.items()}
        sigmas = {f"{k}_sigma": _array(sigma, k, s, "sigma: ") for k, s in PARAMETERS.items()}
        res = d.get("residuals") or {}
        diag = d.get("diagnostics") or {}
        iv = np.asarray(diag.get("static_intervals_s") or np.zeros((0, 2)), dtype=float)
        return cls(
            **values, **sigmas,
            accel_residual_rms=float(res.get("accel_rms_mps2", np.nan)),
            gyro_residual_rms=float(res.get("gyro_rms_rad", np.nan)),
            threshold_multiple=float(diag.get("threshold_multiple", np.nan)),
            n_static_intervals=int(diag.get("n_static_intervals", len(iv))),
            n_distinct_orientations=int(diag.get("n_distinct_orientations", 0)),
            static_intervals=iv.reshape(-1, 2),
            poorly_determined=[str(p) for p in diag.get("poorly_determined") or []],
            accel_condition=float(diag.get("accel_condition_number", np.nan)),
            gyro_condition=float(diag.get("gyro_condition_number", np.nan)),
            accel_chi2=float(res.get("accel_chi2", np.nan)),
            gyro_chi2=float(res.get("gyro_chi2", np.nan)),
            gravity=float(diag.get("gravity_magnitude", 9.81)),
            session_time_ns=int(diag.get("session_time_ns", 0)),
            prior_source=diag.get("prior"),
            threshold_scan=[dict(e) for e in diag.get("threshold_scan") or []],
        )
