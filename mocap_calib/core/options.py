"""What a calibration can be told: the options of ``calibrate`` that reach the core."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocap_calib.core.model.effects import EFFECTS, Model
from mocap_calib.core.model.types import NoiseModel
from mocap_calib.core.params import check_options, param
from mocap_calib.core.plausible import PlausibleLimits
from mocap_calib.core.policy import GRAVITY
from mocap_calib.core.position.graph import Prior
from mocap_calib.errors import InputError


@dataclass
class CalibrationOptions:
    """Everything a calibration can be told. The fields declared with :func:`param` are the
    options of ``calibrate`` (and of the commands that calibrate: ``diagnose``, ``batch``);
    the rest are set by the workflow from files (noise model, priors, limits) or by the core's
    own callers.

    Attributes (not options):
        noise: IMU and mocap noise (default: EuRoC ADIS16448, Vicon).
        priors: earlier results entering as prior factors.
        plausible: the limits of a physically possible answer.
        max_mocap_rate: the position stage decimates faster mocap streams to this rate (Hz).
        adapt_noise: re-estimate the mocap noise level from the residuals (and, with
            ``noise_from_data``, identify every level from the windows' likelihood).
        sensitivity: refit with the IMU noise densities scaled by 3 and 1/3 and under the
            correlated mocap noise model.
        effect_tests: test every canonical effect the model lacks at the solution.
    """

    model: Model = param(
        Model(("time_offset",)), "the measurement model: base plus effects joined by '+', "
        "e.g. base+time_offset+accel_delay, or auto (the effects the session shows, chosen by "
        "the diagnosis' tests); effects (docs/conventions.md gives each one's form): "
        + ", ".join(EFFECTS),
        parse=Model.parse, metavar="MODEL")
    gravity: float = param(GRAVITY, "the |g| the calibration assumes", unit="m/s^2", lo=5.0,
                           hi=15.0)
    keyframe_spacing: float = param(
        0.5, "keyframe spacing of the attitude and velocity factors (stages 1-2)", unit="s",
        lo=0.05, hi=10.0)
    window: float = param(5.0, "length of the position-factor windows", unit="s", lo=0.5,
                          hi=60.0)
    time_offset: float | None = param(
        None, "a known clock offset t_d: an IMU sample stamped t happened at mocap time "
        "t + t_d; with time_offset in the model it only replaces the coarse search", unit="s",
        show_default=False)
    max_offset: float | None = param(
        None, "search the clock offset only within +-this of the raw stamps", unit="s",
        lo=0.0, lo_open=True, show_default=False)
    max_iterations: int = param(
        30, "most Levenberg-Marquardt iterations per solve (a solve still improving at the "
        "limit is retried once from where it stopped, then the command exits 4)", lo=1,
        hi=10_000)
    segments: int = param(
        3, "calibrate this many time segments on their own and compare them (consistency; 0: "
        "skip)", lo=2, hi=20, also=(0,))
    robust: bool = param(True, "down-weight mocap outliers (--no-robust: every sample counts "
                         "fully)")
    noise_from_data: bool = param(
        True, "identify the IMU's and the mocap's noise levels from the data (the windows' "
        "likelihood: in flight the rotors' vibration adds to the data sheet's, and mocap noise "
        "is correlated) and use them where the data contradict the densities given; "
        "--fixed-noise holds the given ones", decls=("--noise-from-data/--fixed-noise",))
    accept_implausible: bool = param(
        False, "write an answer that fails the plausibility checks (marked as such) instead of "
        "exiting 4", decls=("--accept-implausible",))
    trust_prior: bool = param(
        False, "use a --prior even where this session's data contradict it (noted, and marked "
        "in the result's priors section) instead of exiting 2", decls=("--trust-prior",))
    noise: NoiseModel = field(default_factory=NoiseModel)
    priors: list[Prior] = field(default_factory=list)
    plausible: PlausibleLimits = field(default_factory=PlausibleLimits)
    max_mocap_rate: float = 120.0
    adapt_noise: bool = True
    sensitivity: bool = True
    effect_tests: bool = True

    def validate(self) -> None:
        check_options(self)
        nz = self.noise
        for k, v in nz.to_dict().items():
            if k.startswith("mocap_noise_corr"):
                continue
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"noise model: {k} = {v} must be a positive number")
        if not (0.0 <= nz.mocap_noise_corr_time <= 10.0
                and 0.0 <= nz.mocap_noise_corr_fraction < 1.0):
            raise InputError("noise model: mocap_noise_corr_time must be 0-10 s and "
                             "mocap_noise_corr_fraction in [0, 1)")
