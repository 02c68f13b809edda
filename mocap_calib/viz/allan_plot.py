"""Rerun recording of Allan deviation curves and their fitted noise model.

Rerun's time-series view has no logarithmic axes, so the recording draws the log-log plot
itself:

* x: a sequence timeline ``log10_tau_x1000`` holding ``round(1000 log10(tau / 1 s))``. Its
  grid lines fall on decades: 0 is tau = 1 s, 1000 is 10 s, 2000 is 100 s, -1000 is 0.1 s.
  (Octave-spaced tau become equally spaced points.)
* y: ``log10`` of the Allan deviation in the sensor's unit (rad/s or m/s^2): -4 is 1e-4.

One view per sensor and axis (``/gyroscope/x``, ... ``/accelerometer/z``) holds:

* ``adev``: the measured overlapping Allan deviation (markers);
* ``adev_upper``, ``adev_lower``: its 1-sigma band;
* ``fit``: the fitted model ``sqrt(N^2/tau + B^2 2ln2/pi + K^2 tau/3)``;
* ``white_noise``: the -1/2 line ``N / sqrt(tau)`` (reads ``N`` at tau = 1 s, x = 0);
* ``random_walk``: the +1/2 line ``K sqrt(tau / 3)`` (reads ``K`` at tau = 3 s, x = 477);
* ``bias_instability``: the flat line ``0.664 B`` at the reported bias instability.

``/README`` is a text document that repeats this legend with the fitted values.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from mocap_calib.core.intrinsics.noise_result import AllanResult, SensorNoise

Array = NDArray[np.float64]

TIMELINE = "log10_tau_x1000"

_UNITS = {"gyroscope": ("rad/s", "rad/s/sqrt(Hz)", "rad/s^2/sqrt(Hz)"),
          "accelerometer": ("m/s^2", "m/s^2/sqrt(Hz)", "m/s^3/sqrt(Hz)")}

# Series styles: name -> (RGBA colour, line width).
_STYLE: dict[str, tuple[tuple[int, int, int, int], float]] = {
    "adev": ((30, 30, 30, 255), 3.0),  # marker size
    "adev_upper": ((150, 150, 150, 255), 1.0),
    "adev_lower": ((150, 150, 150, 255), 1.0),
    "fit": ((214, 39, 40, 255), 2.5),
    "white_noise": ((31, 119, 180, 255), 1.5),
    "random_walk": ((44, 160, 44, 255), 1.5),
    "bias_instability": ((255, 127, 14, 255), 1.5),
}


def _log10(x: Array) -> Array:
    with np.errstate(divide="ignore", invalid="ignore"):
        y = np.log10(np.asarray(x, dtype=float))
    return y


def _series(s: SensorNoise, ax: int) -> dict[str, Array]:
    """log10 of every curve of one axis at the measured tau (NaN where undefined)."""
    tau = s.tau
    adev = s.adev[ax]
    sig = s.adev_sigma[ax]
    K = s.random_walk_fit[ax]
    out = {
        "adev": adev,
        "adev_upper": adev + sig,
        "adev_lower": np.where(adev - sig > 0, adev - sig, np.nan),
        "fit": s.adev_fit[ax],
        "white_noise": s.noise_density[ax] / np.sqrt(tau),
        "random_walk": (K * np.sqrt(tau / 3.0)) if K > 0 else np.full_like(tau, np.nan),
        "bias_instability": np.full_like(tau, 0.664 * s.bias_instability[ax]),
    }
    return {k: _log10(v) for k, v in out.items()}


def _readme(result: AllanResult) -> str:
    lines = [
        "# Allan deviation (log-log)",
        "",
        f"Static log: {result.duration_s / 3600:.2f} h at {result.rate_hz:.4g} Hz "
        f"({result.n_samples} samples).",
        "",
        f"* **x**: timeline `{TIMELINE}` = round(1000 log10(tau / 1 s)): 0 is 1 s, "
        "1000 is 10 s, 2000 is 100 s, -1000 is 0.1 s.",
        "* **y**: log10 of the Allan deviation (rad/s for the gyroscope, m/s^2 for the "
        "accelerometer): -4 is 1e-4.",
        "* `adev` measured (grey band: 1-sigma), `fit` the model "
        "sqrt(N^2/tau + B^2 2ln2/pi + K^2 tau/3), `white_noise` N/sqrt(tau) (reads N at x=0), "
        "`random_walk` K sqrt(tau/3) (reads K at tau=3 s, x=477), `bias_instability` 0.664 B.",
        "",
        "| sensor | axis | N | K | B |",
        "|---|---|---|---|---|",
    ]
    for s in (result.gyroscope, result.accelerometer):
        _, nu, ku = _UNITS[s.sensor]
        for ax in range(3):
            K = s.random_walk[ax]
            k_txt = f"{K:.4g} {ku}" if np.isfinite(K) else "not resolved"
            lines.append(f"| {s.sensor} | {'xyz'[ax]} | {s.noise_density[ax]:.4g} {nu} | "
                         f"{k_txt} | {s.bias_instability[ax]:.4g} {_UNITS[s.sensor][0]} |")
    return "\n".join(lines)


def write_allan_recording(path: Path | str, result: AllanResult) -> Path:
    """Write the Allan deviation curves of every axis with the fitted model lines.

    Args:
        path: ``.rrd`` file to write (parent folders are created), directly: to replace a file
            whole, write a temporary one and rename it (``io.atomic.write_with``).
        result: output of :func:`mocap_calib.core.intrinsics.allan.characterise_noise`.

    Returns:
        The path written.
    """
    from mocap_calib.viz._rerun import Logger, import_rerun

    import_rerun()  # rerun is imported here, when a recording is written
    import rerun.blueprint as rrb

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sensors = (result.gyroscope, result.accelerometer)
    rows = []
    for s in sensors:
        unit = _UNITS[s.sensor][0]
        rows.append(rrb.Horizontal(*[
            rrb.TimeSeriesView(origin=f"/{s.sensor}/{a}", name=f"{s.sensor} {a}: log10 adev "
                               f"[{unit}] vs 1000 log10(tau/s)") for a in "xyz"]))
    blueprint = rrb.Blueprint(
        rrb.Horizontal(rrb.Vertical(*rows), rrb.TextDocumentView(origin="/README",
                                                                 name="legend"),
                       column_shares=[4, 1]),
        rrb.TimePanel(timeline=TIMELINE), collapse_panels=False)
    # rerun's writer writes ``path`` itself: the workflow gives it a temporary file that
    # mocap_calib.io.atomic renames into place (no half-written recording).
    log = Logger(str(path), blueprint, name="Allan deviation")
    rr = log.rr
    try:
        log.text("/README", _readme(result), markdown=True)
        for s in sensors:
            x = np.round(1000.0 * np.log10(s.tau)).astype(np.int64)
            for ax in range(3):
                for name, y in _series(s, ax).items():
                    entity = f"/{s.sensor}/{'xyz'[ax]}/{name}"
                    color, width = _STYLE[name]
                    if name == "adev":  # measured points as markers, model curves as lines
                        log.rec.log(entity, rr.SeriesPoints(colors=[color], names=[name],
                                                            marker_sizes=[width]), static=True)
                    else:
                        log.style(entity, name, color, width)
                    ok = np.isfinite(y)
                    if ok.any():
                        log.scalars(entity, x[ok], y[ok], timeline=TIMELINE, sequence=True)
    finally:
        log.close()
    return path
