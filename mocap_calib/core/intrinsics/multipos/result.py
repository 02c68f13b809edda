"""The result of a multi-position calibration and its versioned plain-data form (kind
``intrinsics``)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.intrinsics.multipos.params import PARAMETERS
from mocap_calib.core.intrinsics.multipos.units import RawConversion, change_units, imu_tk_form
from mocap_calib.core.policy import GRAVITY
from mocap_calib.core.versioned import check_kind, header

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
        gyro_bias: ``b_g`` in rad/s (mean gyro over the initial static period, or with
            ``G`` the intercept of the static gyro against the specific force).
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
        g_sensitivity: ``G`` in ``w_m = M_g w + G f + b_g`` (rad/s per m/s^2), or None when the
            model leaves it out.
        g_sensitivity_sigma: its 1-sigma.
        g_sensitivity_test: the likelihood-ratio test of ``G`` and the gyro residual with and
            without it (None when not tested).
        raw_input: for raw-count input, the conversion of the counts to the SI readings that
            the values above are for (``x = scale (raw - offset)``); None for SI input.
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
    g_sensitivity: Array | None = None
    g_sensitivity_sigma: Array | None = None
    g_sensitivity_test: dict[str, Any] | None = None
    raw_input: RawConversion | None = None

    def in_units(self, conv: RawConversion) -> MultiposResult:
        """The same calibration for readings converted by ``conv`` from the same raw counts
        (e.g. ``RawConversion.identity("counts")``: the counts themselves)."""
        if self.raw_input is None:
            raise ValueError("an SI calibration has no raw counts to re-express")
        src = self.raw_input
        out: dict[str, Any] = {"raw_input": conv}
        for sensor in ("accel", "gyro"):
            r = conv.scale(sensor) / src.scale(sensor)
            M, b = change_units(getattr(self, f"{sensor}_matrix"),
                                getattr(self, f"{sensor}_bias"), src, conv, sensor)
            out[f"{sensor}_matrix"], out[f"{sensor}_bias"] = M, b
            out[f"{sensor}_matrix_sigma"] = getattr(self, f"{sensor}_matrix_sigma") * r[:, None]
            out[f"{sensor}_bias_sigma"] = getattr(self, f"{sensor}_bias_sigma") * r
        if self.g_sensitivity is not None and self.g_sensitivity_sigma is not None:
            r = conv.gyro_scale / src.gyro_scale
            out["g_sensitivity"] = self.g_sensitivity * r[:, None]
            out["g_sensitivity_sigma"] = self.g_sensitivity_sigma * r[:, None]
        return replace(self, **out)

    def imu_tk(self) -> dict[str, dict[str, Array]]:
        """imu_tk's form per sensor: ``T K (raw - b)`` is the calibrated reading (m/s^2,
        rad/s) of a raw reading (counts for raw input, else the SI reading). ``G`` has no
        place in it."""
        r = self if self.raw_input is None else self.in_units(RawConversion.identity("counts"))
        out = {}
        for sensor in ("accel", "gyro"):
            T, K, b = imu_tk_form(getattr(r, f"{sensor}_matrix"), getattr(r, f"{sensor}_bias"))
            out[sensor] = {"T": T, "K": K, "b": b}
        return out

    def to_dict(self) -> dict[str, Any]:
        """``kind``/``version``, the intrinsics keys of ``docs/conventions.md`` (with
        ``g_sensitivity`` when modelled), ``raw_input`` for raw counts, then ``sigma``,
        ``residuals``, imu_tk's form and ``diagnostics`` (plain Python types, for YAML)."""
        d: dict[str, Any] = {
            **header(KIND, VERSION),
            "accel_matrix": self.accel_matrix.tolist(),
            "accel_bias": self.accel_bias.tolist(),
            "gyro_matrix": self.gyro_matrix.tolist(),
            "gyro_bias": self.gyro_bias.tolist(),
        }
        sigma = {
            "accel_matrix": self.accel_matrix_sigma.tolist(),
            "accel_bias": self.accel_bias_sigma.tolist(),
            "gyro_matrix": self.gyro_matrix_sigma.tolist(),
            "gyro_bias": self.gyro_bias_sigma.tolist(),
        }
        if self.g_sensitivity is not None and self.g_sensitivity_sigma is not None:
            d["g_sensitivity"] = self.g_sensitivity.tolist()
            sigma["g_sensitivity"] = self.g_sensitivity_sigma.tolist()
        if self.raw_input is not None:
            d["raw_input"] = self.raw_input.to_dict()
        d["sigma"] = sigma
        d.update(self._figures())
        return d

    def _figures(self) -> dict[str, Any]:
        """``residuals``, ``imu_tk`` and ``diagnostics`` of :meth:`to_dict`."""
        tk = {s: {k: v.tolist() for k, v in m.items()} for s, m in self.imu_tk().items()}
        tk["model"] = ("calibrated = T K (raw - b); T, K, b as imu_tk's CalibratedTriad"
                       + ("" if self.g_sensitivity is None else "; G not included"))
        return {
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
                "threshold_meaning": "static if |var_w(a)| < k |var_init(a)| (imu_tk)",
                "g_sensitivity_test": self.g_sensitivity_test,
            },
            "imu_tk": tk,
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
            gravity=float(diag.get("gravity_magnitude", GRAVITY)),
            session_time_ns=int(diag.get("session_time_ns", 0)),
            prior_source=diag.get("prior"),
            threshold_scan=[dict(e) for e in diag.get("threshold_scan") or []],
            g_sensitivity_test=diag.get("g_sensitivity_test"),
            **_optional(d, sigma),
        )


def _optional(d: Mapping[str, Any], sigma: Mapping[str, Any]) -> dict[str, Any]:
    """``g_sensitivity`` (with its sigma) and ``raw_input`` when the file has them."""
    out: dict[str, Any] = {}
    if d.get("g_sensitivity") is not None:
        out["g_sensitivity"] = _array(d, "g_sensitivity", (3, 3))
        out["g_sensitivity_sigma"] = _array(sigma, "g_sensitivity", (3, 3), "sigma: ")
    if d.get("raw_input") is not None:
        try:
            out["raw_input"] = RawConversion.from_dict(d["raw_input"])
        except (KeyError, TypeError) as err:
            raise ValueError(f"malformed 'raw_input' ({err})") from None
    return out
