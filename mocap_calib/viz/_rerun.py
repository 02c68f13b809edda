"""Thin helpers around rerun-sdk 0.41; every rerun import of the package goes through here.

Nothing here imports rerun at module import time: :func:`import_rerun` does, when a recording
is actually written, so the CLI and the core start without loading the viewer SDK.
"""

from __future__ import annotations

import copy
import errno
from collections.abc import Sequence
from types import ModuleType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mocap_calib.errors import CalibrationError

Array = NDArray[np.float64]

APPLICATION_ID = "mocap_calib"
TIMELINE = "t"  # mocap time, s since the mocap origin (tau)
ITERATION = "iteration"  # solver iterations of the position stage
IMU_GAPS = "imu_gaps"  # one span series per IMU gap, shown on every plot of timeline t
AXES = ("x", "y", "z")

# Per-axis colours: saturated for "after" / measured, pale for "before" / predicted.
AXIS_RGB = ((230, 60, 60), (60, 170, 60), (60, 110, 230))
PALE_RGB = ((240, 170, 170), (170, 215, 170), (170, 190, 240))
GRAY = (150, 150, 150)


def import_rerun() -> ModuleType:
    """Import ``rerun`` or raise a one-line error saying how to install it."""
    try:
        import rerun as rr
    except ImportError as err:  # pragma: no cover - rerun-sdk is a dependency
        raise CalibrationError(f"rerun-sdk is not installed ({err}); install it with "
                               "pip install 'rerun-sdk==0.41.*'") from None
    return rr


class Logger:
    """A headless rerun recording stream writing to one file, with series helpers.

    Args:
        path: the ``.rrd`` file to write.
        blueprint: optional default blueprint (layout) stored in the file.
        name: recording name shown by the viewer.
    """

    def __init__(self, path: str, blueprint: Any = None, name: str | None = None) -> None:
        self.rr = import_rerun()
        # No make_default: the global stream is left alone, nothing is spawned.
        self.rec = self.rr.RecordingStream(APPLICATION_ID)
        try:
            self.rec.save(path, default_blueprint=blueprint)
        except RuntimeError as err:  # rerun's own writer: an OSError like any other write's
            raise OSError(errno.EIO, f"rerun cannot write it: {err}") from None
        if name:
            self.rec.send_recording_name(name)
        self.prefix = ""

    def at(self, prefix: str) -> Logger:
        """The same stream, every entity path under ``prefix/`` (another take's series)."""
        other = copy.copy(self)
        other.prefix = f"{self.prefix}{prefix.strip('/')}/"
        return other

    def path(self, path: str) -> str:
        return f"{self.prefix}{path}"

    def log(self, path: str, *args: Any, **kwargs: Any) -> None:
        self.rec.log(self.path(path), *args, **kwargs)

    def send_columns(self, path: str, **kwargs: Any) -> None:
        self.rec.send_columns(self.path(path), **kwargs)

    def close(self) -> None:
        """Flush everything and close the file.

        Raises:
            OSError: rerun's writer failed (it names no cause: a full disk, most often).
        """
        try:
            self.rec.flush()
        except RuntimeError as err:
            raise OSError(errno.EIO, f"rerun's file writer failed ({err}); is the disk full?"
                          ) from None
        finally:
            self.rec.disconnect()

    # ------------------------------------------------------------------ series
    def style(self, path: str, name: str, color: Sequence[int], width: float = 1.5) -> None:
        """Static line style (legend name, colour, width) of one scalar series."""
        self.log(path, self.rr.SeriesLines(names=[name], colors=[list(color)],
                                           widths=[width]), static=True)

    def scalars(self, path: str, t: Array, values: Array, *, timeline: str = TIMELINE,
                sequence: bool = False) -> None:
        """One scalar series in a single chunk (``send_columns``).

        Args:
            path: entity path.
            t: (n,) time stamps: seconds (duration timeline) or integers (sequence).
            values: (n,) values (logged as float64, unchanged).
            timeline: timeline name.
            sequence: ``t`` is a sequence index rather than seconds.
        """
        rr = self.rr
        t = np.asarray(t)
        index = (rr.TimeColumn(timeline, sequence=t.astype(np.int64)) if sequence
                 else rr.TimeColumn(timeline, duration=t.astype(np.float64)))
        self.send_columns(path, indexes=[index],
                          columns=rr.Scalars.columns(scalars=np.asarray(values, np.float64)))

    def xyz(self, prefix: str, t: Array, values: Array, label: str, unit: str, *,
            pale: bool = False, timeline: str = TIMELINE, sequence: bool = False,
            width: float = 1.5) -> None:
        """Three series ``prefix/x``, ``prefix/y``, ``prefix/z`` from an (n, 3) array."""
        colors = PALE_RGB if pale else AXIS_RGB
        for i, axis in enumerate(AXES):
            path = f"{prefix}/{axis}"
            self.style(path, f"{label} {axis} [{unit}]", colors[i], width)
            self.scalars(path, t, values[:, i], timeline=timeline, sequence=sequence)

    def text(self, path: str, text: str, markdown: bool = False) -> None:
        """A static text document."""
        media = self.rr.MediaType.MARKDOWN if markdown else self.rr.MediaType.TEXT
        self.log(path, self.rr.TextDocument(text, media_type=media), static=True)


def default_blueprint(stages: Sequence[str], has_rotation: bool,
                      diagnose: Sequence[tuple[str, Sequence[str]]], has_solver: bool,
                      has_imu_gaps: bool = False,
                      other_takes: Sequence[tuple[int, bool]] = ()) -> Any:
    """The viewer layout: 3D scene and summary on the left, tabs of time series on the right.

    Args:
        stages: residual stages present (``attitude``, ``velocity``, ``position``).
        has_rotation: the position stage has its rotation residuals.
        diagnose: per diagnose step, its entity name (``diagnose/<step>``) and its stages.
        has_solver: solver iterations were logged.
        has_imu_gaps: ``imu_gaps/...`` spans were logged: every plot on the ``t`` timeline
            shows them.
        other_takes: with several takes, (take number, has IMU gaps) of the second take on:
            each gets a tab with its own scene and series (entities under ``takes/<k>/``).
    """
    import_rerun()
    import rerun.blueprint as rrb

    tabs = _series_tabs(rrb, "", stages, has_rotation, has_imu_gaps)
    if has_solver:
        tabs.append(rrb.Grid(
            *(rrb.TimeSeriesView(origin=f"solver/{k}", name=f"{k} (timeline: iteration)")
              for k in ("cost", "p_MI", "R_MI", "time_offset", "gyro_bias", "accel_bias",
                        "gravity_tilt")), name="solver"))
    if diagnose:
        gaps = [f"+ /{IMU_GAPS}/**"] if has_imu_gaps else []
        tabs.append(rrb.Tabs(*(rrb.Vertical(
            *(rrb.TimeSeriesView(origin=f"diagnose/{step}/{st}", name=f"{step}: {st}",
                                 contents=["+ $origin/before/**", "+ $origin/after/**", *gaps])
              for st in step_stages), name=step) for step, step_stages in diagnose),
            name="diagnose"))
    for k, gaps_k in other_takes:
        prefix = f"takes/{k}/"
        tabs.append(rrb.Vertical(
            rrb.Spatial3DView(origin=f"{prefix}world", name=f"take {k}: trajectory, IMU frame"),
            rrb.Tabs(*_series_tabs(rrb, prefix, stages, has_rotation, gaps_k)),
            row_shares=[2, 3], name=f"take {k}"))
    scene = "trajectory, IMU frame, dead reckoning"
    left = rrb.Vertical(
        rrb.Spatial3DView(origin="world", name=f"take 1: {scene}" if other_takes else scene),
        rrb.Tabs(rrb.TextDocumentView(origin="summary", name="summary"),
                 rrb.TextDocumentView(origin="guide", name="guide")),
        row_shares=[3, 2])
    return rrb.Blueprint(rrb.Horizontal(left, rrb.Tabs(*tabs), column_shares=[2, 3]),
                         rrb.TimePanel(timeline=TIMELINE), collapse_panels=False)


def _series_tabs(rrb: Any, prefix: str, stages: Sequence[str], has_rotation: bool,
                 has_imu_gaps: bool) -> list[Any]:
    """The residual, IMU and dead-reckoning tabs of one take (its entities under ``prefix``)."""
    gaps = [f"+ /{prefix}{IMU_GAPS}/**"] if has_imu_gaps else []

    def view(origin: str, name: str, contents: Sequence[str] = ("+ $origin/**",)) -> Any:
        return rrb.TimeSeriesView(origin=f"{prefix}{origin}", name=name,
                                  contents=[*contents, *gaps])

    units = {"attitude": "deg", "velocity": "m/s", "position": "m"}
    res_views = []
    for st in stages:
        res_views.append(view(f"residuals/{st}", f"{st} residual ({units.get(st, '')})",
                              ["+ $origin/before/**", "+ $origin/after/**"]))
    if has_rotation:
        res_views.append(view("residuals/position/rotation",
                              "position-stage attitude residual (deg)"))
    # Query expressions only know a trailing "/**" wildcard: list the weight series.
    res_views.append(view("residuals", "robust weights (1 = inlier)",
                          [f"+ $origin/{st}/weight" for st in stages]))
    imu_views = [
        view("imu/gyro", "gyro measured vs predicted (rad/s)",
             ["+ $origin/measured/**", "+ $origin/predicted/**"]),
        view("imu/gyro/difference", "gyro measured - predicted"),
        view("imu/accel", "accel measured vs predicted (m/s^2)",
             ["+ $origin/measured/**", "+ $origin/predicted/**"]),
        view("imu/accel/difference", "accel measured - predicted"),
    ]
    dr_views = [view("dead_reckoning", f"dead-reckoning {q} error at the end",
                     [f"+ $origin/{k}/{q}_error" for k in ("before", "after")])
                for q in ("position", "attitude")]
    return [rrb.Vertical(*res_views, name="residuals"),
            rrb.Vertical(*imu_views, name="IMU"),
            rrb.Vertical(*dr_views, name="dead reckoning")]
