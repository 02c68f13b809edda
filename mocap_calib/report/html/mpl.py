"""matplotlib without pyplot: figures on the Agg canvas, PNG bytes, and data thinning.

matplotlib is imported here, inside functions, so that only a run that writes an HTML report
pays for it. No global state (pyplot, rcParams) is touched: each figure gets its own style.
"""

from __future__ import annotations

import io
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from matplotlib.figure import Figure as MplFigure

Array = NDArray[np.float64]

#: Resolution of the PNGs: enough for reading numbers off axes, small files.
DPI = 90
#: Most points per plotted line (min/max envelope beyond that).
MAX_POINTS = 2000

STYLE: dict[str, Any] = {
    "font.size": 8.5, "axes.titlesize": 9, "axes.labelsize": 8.5, "legend.fontsize": 7.5,
    "xtick.labelsize": 7.5, "ytick.labelsize": 7.5, "axes.grid": True, "grid.alpha": 0.3,
    "lines.linewidth": 0.9,
}
AXIS_COLORS = ("#d62728", "#2ca02c", "#1f77b4")  # x, y, z


def new_figure(width_in: float, height_in: float, **margins: float) -> MplFigure:
    """A figure on the Agg canvas (no GUI, no pyplot), with fixed margins (``left``,
    ``right``, ``top``, ``bottom``, ``wspace``, ``hspace`` as in ``subplots_adjust``): an
    automatic layout engine costs several times the drawing."""
    import matplotlib

    with matplotlib.rc_context(STYLE):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(width_in, height_in), dpi=DPI)
        FigureCanvasAgg(fig)
        m = {"left": 0.08, "right": 0.98, "top": 0.9, "bottom": 0.14, "wspace": 0.25,
             "hspace": 0.12}
        m.update(margins)
        fig.subplots_adjust(**m)
    return fig


def log_axes(ax: Any, x: bool = True, y: bool = True) -> None:
    """Log scales without minor tick labels (the slow part of drawing log axes)."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    plain = FuncFormatter(lambda v, _pos: f"{v:g}")  # no mathtext: several times faster
    for on, axis, setter in ((x, ax.xaxis, ax.set_xscale), (y, ax.yaxis, ax.set_yscale)):
        if on:
            setter("log")
            axis.set_major_formatter(plain)
            axis.set_minor_formatter(NullFormatter())


def styled() -> Any:
    """Context manager applying :data:`STYLE` (axes created inside it take it)."""
    import matplotlib

    return matplotlib.rc_context(STYLE)


def to_png(fig: MplFigure) -> bytes:
    """The figure as PNG bytes (no metadata, so the same figure gives the same bytes)."""
    buf = io.BytesIO()
    with styled():
        fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    return buf.getvalue()


def thin(t: Array, y: Array, max_points: int = MAX_POINTS) -> tuple[Array, Array]:
    """At most ``max_points`` of a series ``y(t)`` (1-D), keeping each bucket's minimum and
    maximum in time order, so spikes and outliers stay visible."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    n = len(t)
    if n <= max_points:
        return t, y
    width = int(np.ceil(n / max(1, max_points // 2)))
    buckets = int(np.ceil(n / width))
    pad = np.full(buckets * width, np.nan)
    pad[:n] = y
    grid = pad.reshape(buckets, width)
    finite = np.isfinite(grid)
    lo = np.argmin(np.where(finite, grid, np.inf), axis=1)
    hi = np.argmax(np.where(finite, grid, -np.inf), axis=1)
    base = np.arange(buckets) * width
    idx = np.stack([np.minimum(lo, hi), np.maximum(lo, hi)], axis=1) + base[:, None]
    idx = np.unique(np.minimum(idx.ravel(), n - 1))
    return t[idx], y[idx]


def every(n: int, max_points: int = MAX_POINTS) -> slice:
    """A stride that leaves at most ``max_points`` of ``n`` samples (for paths, not signals)."""
    return slice(None, None, max(1, int(np.ceil(n / max_points))))


def fmt(v: float | None, digits: int = 4) -> str:
    """A number with ``digits`` significant digits ("-" for None / NaN)."""
    if v is None or not np.isfinite(v):
        return "-"
    return f"{v:.{digits}g}"
