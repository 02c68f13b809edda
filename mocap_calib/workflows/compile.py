"""``compile``: compile the numerical kernels into their cache once, at install time, so that no
later run compiles them (the install scripts run it).

The kernels are compiled for the argument types a calibration passes them by running one: a
short simulated session calibrated in memory (no file is read or written besides the cache).
Whatever a kernel's module changes, the types are those the calibration uses.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from mocap_calib.core import jit

#: Length of the simulated session (s): the shortest that runs every stage of the calibration
#: with margin (:data:`~mocap_calib.core.policy.MIN_SESSION_S` is 10 s).
SESSION_S = 20.0


@dataclass
class CompileRequest:
    """``compile`` takes no options."""


@dataclass(frozen=True)
class CompileReport:
    """What :func:`compile_kernels` did.

    Attributes:
        compiled: kernels compiled (and cached) by this run, as ``module.function``.
        loaded: kernels that were in the cache already.
        uncached: kernels without a writable cache folder (every run compiles them).
        seconds: wall time of the run.
    """

    compiled: list[str]
    loaded: list[str]
    uncached: list[str]
    seconds: float

    def lines(self) -> list[str]:
        """The command's output."""
        if self.compiled:
            out = [f"compiled {len(self.compiled)} kernels into the cache in {self.seconds:.1f} s"
                   + (f" ({len(self.loaded)} were cached already)" if self.loaded else "")]
        else:
            out = [f"the kernels were cached already ({len(self.loaded)} loaded; "
                   f"{self.seconds:.1f} s)"]
        if self.uncached:
            out.append("warning: no writable cache folder for " + ", ".join(self.uncached)
                       + ": every run compiles them; set NUMBA_CACHE_DIR to a writable folder")
        return out


def compile_kernels(request: CompileRequest | None = None) -> CompileReport:
    """Run a short simulated calibration, which compiles (or loads) every kernel it uses."""
    from mocap_calib.core.model.effects import CLOCK_OFFSET
    from mocap_calib.core.options import CalibrationOptions
    from mocap_calib.core.pipeline.calibrate import calibrate
    from mocap_calib.sim.flight import SimConfig, simulate_flight

    t0 = time.perf_counter()
    sim = simulate_flight(SimConfig(seed=0, duration=SESSION_S,
                                    effects={CLOCK_OFFSET.name: [0.004]}))
    calibrate(sim.imu, sim.mocap, CalibrationOptions())
    compiled = jit.compiled_in_process()
    return CompileReport(compiled, jit.loaded_in_process(),
                         [k for k in jit.uncached_kernels() if k in compiled],
                         time.perf_counter() - t0)
