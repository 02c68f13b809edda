"""What ``--effect NAME[=VALUE]`` injects into a simulated flight, and the drawn truth.

An effect of the model ladder is described by its registry record
(:class:`~mocap_calib.core.model.effects.EffectSim`: default, help, how to draw); a stream
fault by :data:`~mocap_calib.sim.stream_faults.FAULTS`. The truth is collected by kind
(``Effect.acts_on`` and ``sensor``), so an effect of an existing kind needs only its registry
entry; the measurement model that applies it is written out in :mod:`mocap_calib.sim.flight`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.model.effects import EFFECTS, Effect, EffectSim
from mocap_calib.errors import InputError
from mocap_calib.sim.stream_faults import FAULTS, Injected

Array = NDArray[np.float64]


def injectable() -> tuple[str, ...]:
    """Every name ``--effect`` accepts: the effects of the ladder, then the stream faults."""
    return (*EFFECTS, *FAULTS)


#: The quantity each sensor measures: its matrix term of this kind is ``M = I + E``; a term
#: of the other kind is ``E`` times the other quantity (e.g. the gyro's g-sensitivity).
OWN_QUANTITY = {"gyro": "w", "accel": "f"}


def effect_help(name: str) -> str:
    """What ``NAME=VALUE`` means (for ``--help`` and errors)."""
    if name in FAULTS:
        return FAULTS[name].help
    return sim_of(EFFECTS[name]).help


def sim_of(eff: Effect) -> EffectSim:
    """The record's simulation (a record without one is refused)."""
    if eff.sim is None:
        raise InputError(f"effect '{eff.name}' has no simulation in the effect registry; "
                         "give its record an EffectSim")
    return eff.sim


def parse_effect(spec: str) -> tuple[str, list[float] | None]:
    """Parse ``NAME`` or ``NAME=VALUE`` or ``NAME=v1,v2,...``."""
    name, _, value = spec.partition("=")
    name = name.strip()
    known = injectable()
    if name not in known:
        raise InputError(f"unknown effect '{name}'; choose one of: {', '.join(known)}")
    if not value.strip():
        return name, None
    try:
        values = [float(v) for v in value.split(",")]
    except ValueError:
        raise InputError(f"effect '{spec}': value must be a number or comma-separated numbers, "
                         f"e.g. {name}=0.01") from None
    if not all(np.isfinite(values)):
        raise InputError(f"effect '{spec}': value must be finite")
    _check_values(spec, name, values)
    return name, values


def _check_values(spec: str, name: str, values: list[float]) -> None:
    """The count, sign and range rules of ``name``'s record."""
    if name in FAULTS:
        fault = FAULTS[name]
        counts, non_negative, bounds = fault.counts, fault.events, None
    else:
        sim = sim_of(EFFECTS[name])
        counts = sim.value_counts(EFFECTS[name].dim)
        non_negative, bounds = sim.non_negative, sim.bounds
    if len(values) not in counts:
        allowed = " or ".join(str(c) for c in counts)
        raise InputError(f"effect '{spec}': give {allowed} value(s) ({effect_help(name)})")
    if non_negative and len(values) == 1 and values[0] < 0:
        raise InputError(f"effect '{spec}': the magnitude must not be negative")
    if bounds is not None and len(values) == 1 and not bounds[0] < values[0] < bounds[1]:
        raise InputError(f"effect '{spec}': give a value between {bounds[0]:g} and "
                         f"{bounds[1]:g} ({effect_help(name)})")
    if name in FAULTS and FAULTS[name].events and (values[0] != int(values[0])
                                                   or values[0] > 1000):
        raise InputError(f"effect '{spec}': give a whole number of events between 0 and 1000")
    if name in FAULTS and not FAULTS[name].events and min(values) <= 0:
        raise InputError(f"effect '{spec}': every length must be positive, in s")


@dataclass
class Truth:
    """The injected effects' true values, by kind (neutral when none is injected).

    ``matrix[(sensor, quantity)]``: the sensor's matrix on the true rate (``w``) or specific
    force (``f``), ``I + E`` on its own quantity, ``E`` on the other; ``rate[sensor]``: its
    bias trend per s; ``theta[name]``: each injected effect's parameter vector (the truth file's
    values).
    """

    t_d: float
    g: float
    drift: float = 0.0  # the IMU clock's rate error s
    lag: float = 0.0  # the accelerometer's lag behind the gyro (s)
    r_size: Array = field(default_factory=lambda: np.zeros(6))  # r_y, r_z (m)
    matrix: dict[tuple[str, str], Array] = field(default_factory=dict)
    rate: dict[str, Array] = field(default_factory=dict)
    theta: dict[str, Array] = field(default_factory=dict)

    def sensor_matrix(self, sensor: str, quantity: str) -> Array:
        own = OWN_QUANTITY[sensor] == quantity
        return self.matrix.get((sensor, quantity), np.eye(3) if own else np.zeros((3, 3)))

    def bias_rate(self, sensor: str) -> Array:
        return self.rate.get(sensor, np.zeros(3))


def _matrix(rng: np.random.Generator, values: list[float] | None, default: float,
            lower: bool) -> Array:
    if values is not None and len(values) == 9:
        m = np.asarray(values, dtype=float).reshape(3, 3)
    else:
        scale = default if values is None else values[0]
        m = rng.normal(0.0, scale, (3, 3))
    return np.tril(m) if lower else m


def _vectors(rng: np.random.Generator, values: list[float] | None, default: float,
             dim: int) -> Array:
    if values is not None and len(values) == dim:
        return np.asarray(values, dtype=float)
    mag = default if values is None else values[0]
    parts = []
    for _ in range(dim // 3):
        d = rng.normal(size=3)
        parts.append(mag * d / np.linalg.norm(d))
    return np.concatenate(parts)


def _draw(rng: np.random.Generator, eff: Effect, values: list[float] | None) -> Array:
    """One effect's truth: a 3x3 matrix ``E`` for matrix draws, else its parameter vector."""
    sim = sim_of(eff)
    if sim.draw in ("matrix", "lower_matrix"):
        return _matrix(rng, values, sim.default, sim.draw == "lower_matrix")
    if sim.draw == "vectors":
        return _vectors(rng, values, sim.default, eff.dim)
    if sim.draw == "signed" and values is None:
        return np.array([sim.default * rng.choice([-1.0, 1.0])])
    return np.array([sim.default if values is None else values[0]])


def draw_truth(rng: np.random.Generator, effects: Injected, gravity: float) -> Truth:
    """The injected effects' values, given or drawn at their default magnitude, in registry
    order (so the seed fixes every draw whatever order the effects were given in)."""
    tr = Truth(t_d=0.0, g=gravity)
    for eff in EFFECTS.values():
        if eff.name not in effects:
            continue
        value = _draw(rng, eff, effects[eff.name])
        if eff.acts_on in ("w", "f"):
            own = OWN_QUANTITY[eff.sensor] == eff.acts_on
            tr.matrix[(eff.sensor, eff.acts_on)] = np.eye(3) + value if own else value
            tr.theta[eff.name] = np.einsum("kij,ij->k", eff.basis, value)
            continue
        tr.theta[eff.name] = value
        if eff.acts_on == "time":
            tr.rate[eff.sensor] = value
        elif eff.acts_on == "size":
            tr.r_size = value
        else:
            setattr(tr, _SCALAR_SLOT[eff.acts_on], float(value[0]))
    return tr


#: Where the value of a one-number kind goes.
_SCALAR_SLOT = {"clock": "t_d", "gravity": "g", "clock_rate": "drift", "accel_lag": "lag"}


def truth_effects(effects: Injected, tr: Truth) -> dict[str, dict[str, object]]:
    """The truth file's ``effects``: each injected effect's value in the result file's form,
    in the order given."""
    return {name: {EFFECTS[name].param: EFFECTS[name].report_value(tr.theta[name])}
            for name in effects if name in EFFECTS}
