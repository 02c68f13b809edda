"""``--html`` reports of calibrate, diagnose, multipos and allan, read back as a browser would.

Every page must parse (balanced tags), reference nothing outside itself (inline PNGs, in-page
links only), hold the figures each report has (by id), and show the numbers of the YAML that
the same run wrote: every cell tied to a key (``data-key``) holds that key's value, and its
text shows it (to the precision printed). The simulator's truth gives figures the report must
reproduce independently (mocap gaps), and the multi-position per-pose residuals must give the
RMS the fit reported.
"""

from __future__ import annotations

import base64
import math
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from loaded import loaded_by

from mocap_calib.cli.main import main
from mocap_calib.report.html.mpl import thin
from mocap_calib.workflows.simulate import simulate_to_folder

pytestmark = pytest.mark.slow  # full calibrations / diagnoses: not in the quick subset

REPO = Path(__file__).resolve().parents[1]
VOID = {"meta", "img", "br", "hr", "input", "link", "source", "col", "area", "base", "wbr"}

CALIBRATION_FIGURES = ("fig-clock", "fig-consistency", "fig-residuals-attitude",
                       "fig-residuals-velocity", "fig-residuals-position", "fig-spectra-imu",
                       "fig-trajectory", "fig-gaps")
CALIBRATION_TABLES = ("result-table", "stages-table", "clock-table", "plausibility-table",
                      "consistency-table", "consistency-summary", "sensitivity-table",
                      "provenance", "input-files")
CALIBRATION_KEYS = (
    [f"{k}/{i}" for k in ("gyro_bias", "accel_bias", "sigma/gyro_bias", "sigma/accel_bias",
                          "T_marker_imu/translation", "sigma/translation", "sigma/rotation",
                          "gravity_in_mocap") for i in range(3)]
    + [f"T_marker_imu/rotation_wxyz/{i}" for i in range(4)]
    + ["time_offset", "sigma/time_offset", "clock/peak_z", "clock/margin_z",
       "clock/coarse_time_offset", "clock/fine_time_offset", "plausibility/verdict",
       "plausibility/figures/tilt_deg", "consistency/max_pairwise_z/t_d",
       "consistency/birge_ratio/p_MI", "consistency/segments/0/time_offset",
       "sensitivity/moved_sigmas/x3/R_MI", "sensitivity/moved_sigmas/x0.333/t_d",
       "sensitivity/moved_statistical_sigmas/x3/t_d", "stages/2/rms_after/0",
       "stages/0/chi2_per_dof"])


class Page(HTMLParser):
    """What a test needs from a page: ids, figures with captions and data, keyed cells,
    every src/href, and whether the tags balance."""

    def __init__(self, text: str) -> None:
        super().__init__(convert_charrefs=True)
        self.stack: list[str] = []
        self.errors: list[str] = []
        self.ids: dict[str, dict[str, str]] = {}
        self.refs: list[tuple[str, str, str]] = []
        self.cells: list[dict[str, str]] = []
        self.captions: dict[str, str] = {}
        self.images: dict[str, str] = {}
        self.tags: list[str] = []
        self._cell: dict[str, str] | None = None
        self._figure: str | None = None
        self._caption: list[str] | None = None
        self.feed(text)
        self.close()
        if self.stack:
            self.errors.append(f"unclosed {self.stack}")

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = {k: v or "" for k, v in attrs}
        self.tags.append(tag)
        if tag not in VOID:
            self.stack.append(tag)
        if "id" in a:
            if a["id"] in self.ids:
                self.errors.append(f"duplicate id {a['id']}")
            self.ids[a["id"]] = a
        for k in ("src", "href", "action", "poster", "data", "srcset"):
            if k in a:
                self.refs.append((tag, k, a[k]))
        if tag == "figure":
            self._figure = a.get("id")
        if tag == "img" and self._figure:
            self.images[self._figure] = a.get("src", "")
        if tag == "figcaption":
            self._caption = []
        if tag == "td" and "data-key" in a:
            self._cell = dict(a, text="")

    def handle_endtag(self, tag: str) -> None:
        if tag in VOID:
            return
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1:] or 'nothing'}")
            return
        self.stack.pop()
        if tag == "figcaption" and self._figure and self._caption is not None:
            self.captions[self._figure] = "".join(self._caption)
            self._caption = None
        if tag == "figure":
            self._figure = None
        if tag == "td" and self._cell is not None:
            self.cells.append(self._cell)
            self._cell = None

    def handle_data(self, data: str) -> None:
        if self._caption is not None:
            self._caption.append(data)
        if self._cell is not None:
            self._cell["text"] += data


def lookup(d: Any, key: str) -> Any:
    cur = d
    for part in key.split("/"):
        if isinstance(cur, dict):
            assert part in cur, f"{key}: no '{part}' in the YAML"
            cur = cur[part]
        else:
            cur = cur[int(part)]
    return cur


def check_page(text: str, yaml_dict: dict[str, Any], figures: tuple[str, ...],
               keys: list[str] | tuple[str, ...] = ()) -> Page:
    """The checks every report passes; returns the parsed page for more."""
    assert text.startswith("<!DOCTYPE html>")
    page = Page(text)
    assert not page.errors, page.errors[:5]
    assert page.tags.count("html") == 1 and page.tags.count("body") == 1
    # Nothing outside the file: no scripts, stylesheets or frames to fetch, images inline,
    # links only within the page, no URL anywhere in the text.
    for tag in ("script", "link", "iframe", "object", "embed"):
        assert tag not in page.tags, tag
    for tag, attr, value in page.refs:
        if attr == "src":  # inline data only (base64 may spell "http" by chance: not a URL)
            assert value.startswith("data:image/png;base64,"), (tag, value[:40])
            assert re.fullmatch(r"[A-Za-z0-9+/]+=*", value.split(",", 1)[1]), (tag, value[:40])
            continue
        assert "http" not in value.lower(), (tag, attr, value[:80])
        if attr == "href":
            assert value.startswith("#") and value[1:] in page.ids, value
    assert not re.search(r"(https?:|ftp:)//|url\(", text, re.I)
    for fid in figures:
        assert fid in page.ids, f"figure {fid} missing"
        assert page.captions.get(fid), f"figure {fid} has no caption"
        png = base64.b64decode(page.images[fid].split(",", 1)[1])
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 2000, fid
    shown = {c["data-key"] for c in page.cells}
    missing = [k for k in keys if k not in shown]
    assert not missing, f"numbers not in the page: {missing}"
    for c in page.cells:
        check_cell(c, lookup(yaml_dict, c["data-key"]))
    return page


def check_cell(c: dict[str, str], want: Any) -> None:
    key, value, text = c["data-key"], c["data-value"], c["text"].strip()
    if want is None:
        assert value == "null" and text == "-", (key, value, text)
    elif isinstance(want, bool):
        assert value == str(want).lower() and text == value, (key, value, text)
    elif isinstance(want, str):
        assert value == want and text == want, (key, value, text)
    else:
        assert float(value) == pytest.approx(float(want), rel=1e-12, abs=1e-300), key
        shown = float(want) * float(c.get("data-scale", "1"))
        printed = float(text)
        # The text is the value rounded to what it prints: within half its last digit.
        decimals = len(text.split(".")[1].split("e")[0]) if "." in text else 0
        exp = int(text.split("e")[1]) if "e" in text else 0
        tol = 0.5 * 10.0 ** (exp - decimals) * (1 + 1e-9) + 1e-12 * abs(shown)
        assert abs(printed - shown) <= tol, (key, text, shown)


# --------------------------------------------------------------------------------------------
# calibrate
# --------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("html") / "s"
    simulate_to_folder(out, seed=21, duration=40.0, effects=[
        "time_offset=0.005", "mocap_dropouts=3", "mocap_outliers=2"])
    return out


@pytest.fixture(scope="module")
def calibrated(session: Path) -> tuple[dict[str, Any], str, Path]:
    out, html = session.parent / "calib.yaml", session.parent / "calib.html"
    code = main(["calibrate", str(session), "--out", str(out), "--html", str(html), "-q"])
    assert code == 0
    return yaml.safe_load(out.read_text()), html.read_text(encoding="utf-8"), html


def test_calibration_page_holds_every_figure_and_the_yaml_numbers(
        calibrated: tuple[dict[str, Any], str, Path]) -> None:
    d, text, _ = calibrated
    page = check_page(text, d, CALIBRATION_FIGURES, CALIBRATION_KEYS)
    for tid in CALIBRATION_TABLES:
        assert tid in page.ids, tid
    clock = page.ids["fig-clock"]
    for attr, key in (("data-peak-z", "peak_z"), ("data-margin-z", "margin_z"),
                      ("data-fine-time-offset", "fine_time_offset")):
        assert float(clock[attr]) == d["clock"][key]
    cap = page.captions["fig-clock"]
    assert f"{d['clock']['peak_z']:.2f} null sigmas" in cap
    assert f"margin {d['clock']['margin_z']:.2f}" in cap
    assert f"{1e3 * d['clock']['fine_time_offset']:.3f} ms" in cap
    assert page.ids["verdict"] and d["plausibility"]["verdict"] in text
    for note in d["notes"]:
        assert note.split(":")[0] in text


def test_calibration_page_shows_the_simulated_gaps_and_removed_spikes(
        session: Path, calibrated: tuple[dict[str, Any], str, Path]) -> None:
    d, text, _ = calibrated
    page = Page(text)
    truth = yaml.safe_load((session / "truth.yaml").read_text())["simulation"]
    n_gaps = int(page.ids["fig-gaps"]["data-gaps"])
    assert n_gaps == int(page.ids["fig-trajectory"]["data-gaps"])
    starts = [float(x) for x in page.ids["fig-gaps"]["data-gap-starts-s"].split(",")]
    ends = [float(x) for x in page.ids["fig-gaps"]["data-gap-ends-s"].split(",")]
    # Every simulated dropout (0.05-1 s of rows removed) is one of the gaps shown, from the
    # last sample before it to the first after it (100 Hz mocap).
    for t0, length in truth["mocap_gaps_start_length_s"]:
        assert any(a - 0.011 <= t0 <= a + 0.011 and abs((b - a) - length) <= 0.021
                   for a, b in zip(starts, ends, strict=True)), (t0, length, starts, ends)
    # The other gaps are the holes left by the removed marker-swap samples.
    assert n_gaps <= len(truth["mocap_gaps_start_length_s"]) + 2
    removed = d["session"]["mocap_spikes_removed"]
    assert removed > 0  # the simulated marker swaps were caught
    assert int(page.ids["fig-gaps"]["data-removed-spikes"]) == removed
    assert int(page.ids["fig-residuals-position"]["data-removed-spikes"]) == removed
    assert page.ids["fig-residuals-position"]["data-spectrum"] == "yes"
    # No IMU gaps simulated: none shaded, no table of them (tests/test_gaps_viz.py: with them).
    assert d["imu_gaps"]["count"] == 0
    assert page.ids["fig-gaps"]["data-imu-gaps"] == "0"
    assert page.ids["fig-residuals-position"]["data-imu-gaps"] == "0"
    assert "imu-gaps-table" not in page.ids


def test_calibration_page_records_how_it_was_made(
        session: Path, calibrated: tuple[dict[str, Any], str, Path]) -> None:
    import hashlib

    _, text, html = calibrated
    assert f"mocap-calib calibrate {session}" in text and "--html" in text
    imu = session / "mav0" / "imu0" / "data.csv"
    digest = hashlib.sha256(imu.read_bytes()).hexdigest()
    assert digest in text and f">{imu.stat().st_size}<" in text
    assert "mocap-calib 0.1.0" in text
    assert html.stat().st_size < 5e6


@pytest.mark.skipif(shutil.which("chromium") is None and shutil.which("chromium-browser") is None,
                    reason="Debian's chromium is not installed (apt-get install -y chromium)")
def test_render_script_makes_a_picture(calibrated: tuple[dict[str, Any], str, Path],
                                       tmp_path: Path) -> None:
    _, _, html = calibrated
    png = tmp_path / "page.png"
    proc = subprocess.run(["bash", str(REPO / "scripts" / "render_report.sh"), str(html),
                           str(png), "1000", "1400"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert (width, height) == (1000, 1400)
    # A rendered page is not blank: the PNG of a plain white page compresses to a few KB.
    assert len(data) > 50_000


def test_no_matplotlib_without_html() -> None:
    """matplotlib is imported only when a page is drawn."""
    code = ("import mocap_calib.cli.main as m\n"
            "m._register_commands()\n"
            "import mocap_calib.workflows.report_files.pages\n"
            "import mocap_calib.workflows.report_files.intrinsics\n"
            "import mocap_calib.report.html\n")
    assert loaded_by(code, ["matplotlib"]) == []


def test_thin_keeps_the_extremes_in_time_order() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(100_000) * 0.01
    y = rng.normal(size=t.size)
    y[12_345] = 50.0
    y[67_890] = -40.0
    tt, yy = thin(t, y, 1000)
    assert len(tt) <= 1000 and np.all(np.diff(tt) > 0)
    assert yy.max() == 50.0 and yy.min() == -40.0
    assert tt[np.argmax(yy)] == t[12_345]


# --------------------------------------------------------------------------------------------
# diagnose (with the unexplained signature from a hand-made dict)
# --------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def diagnosed(session: Path) -> tuple[dict[str, Any], str]:
    out, html = session.parent / "diag.yaml", session.parent / "diag.html"
    code = main(["diagnose", str(session), "--out", str(out), "--html", str(html),
                 "--candidates", "time_offset+gravity_magnitude", "--max-steps", "2", "-q"])
    assert code == 0
    return yaml.safe_load(out.read_text()), html.read_text(encoding="utf-8")


def test_diagnosis_page_shows_the_steps_and_the_final_calibration(
        diagnosed: tuple[dict[str, Any], str]) -> None:
    d, text = diagnosed
    steps = d["steps"]
    keys = [f"steps/{i}/residuals/{s}_ratio" for i in range(len(steps))
            for s in ("gyro", "accel")]
    keys += [f"steps/0/candidates/{j}/statistic" for j in range(len(steps[0]["candidates"]))]
    keys += [f"final_calibration/{k}" for k in ("gyro_bias/0", "time_offset", "clock/peak_z")]
    page = check_page(text, d, ("fig-diagnose-gap", "fig-diagnose-candidates",
                                *CALIBRATION_FIGURES), keys)
    assert int(page.ids["fig-diagnose-gap"]["data-steps"]) == len(steps)
    assert float(page.ids["fig-diagnose-gap"]["data-threshold-log10-p"]) == \
        d["test"]["threshold_log10_p"]
    assert "fig-unexplained" not in page.ids  # this diagnosis reports none
    assert d["verdict"] in page.ids["verdict"].get("class", "") + text


def test_diagnosis_page_renders_an_unexplained_signature(
        diagnosed: tuple[dict[str, Any], str]) -> None:
    from mocap_calib.core.diagnosis.diagnose import DiagnoseReport
    from mocap_calib.report.html import diagnosis_sections, render_html

    d, _ = diagnosed
    report = DiagnoseReport.from_dict(d)
    # The layout of core/diagnosis/signature.py's unexplained_signature.
    corr = {sig: {"max_abs_corr": c, "residual_axis": "z", "signal_axis": "z",
                  "magnitude_corr": 0.5 * c}
            for sig, c in (("angular_rate", 0.71), ("angular_acceleration", -0.12),
                           ("specific_force", 0.05))}
    unexplained = {
        "gyro": {"ratio_per_axis": [1.1, 0.9, 3.2], "axes_over_floor": ["z"],
                 "band_most_over_floor": "0.5-2 Hz", "correlation": corr,
                 "rms_per_time_segment": [0.8, 1.0, 1.3, 0.9, 1.0, 1.0]},
        "accel": {"ratio_per_axis": [1.0, 1.0, 1.1], "axes_over_floor": [],
                  "band_most_over_floor": "0-0.5 Hz", "correlation": corr,
                  "rms_per_time_segment": [1.0, 1.0, 1.0, 1.0, 1.0, 1.0]},
        "clock_offset_per_segment": {"t_s": [3.3, 10.0, 16.7], "t_d_ms": [4.9, 5.1, 6.2],
                                     "sigma_ms": [0.1, 0.1, 0.1], "slope_ppm": 98.0,
                                     "largest_jump_sigmas": 7.8}}
    report.unexplained = unexplained  # type: ignore[attr-defined]
    text = render_html("t", diagnosis_sections(report))
    page = check_page(text, {**d, "unexplained": unexplained},
                      ("fig-diagnose-gap", "fig-unexplained"),
                      ["unexplained/gyro/correlation/angular_rate/max_abs_corr",
                       "unexplained/gyro/ratio_per_axis/2",
                       "unexplained/clock_offset_per_segment/t_d_ms/2"])
    assert "sec-unexplained" in page.ids
    assert "gyro: axes z, band 0.5-2 Hz" in page.captions["fig-unexplained"]
    # Read from a file, the final calibration has no residual series: the page says so.
    assert "fig-clock" not in page.ids and "not available" in text


# --------------------------------------------------------------------------------------------
# multipos and allan
# --------------------------------------------------------------------------------------------

def test_multipos_page_with_static_intervals_and_per_pose_residuals(tmp_path: Path) -> None:
    sim, out, html = tmp_path / "mp", tmp_path / "mp.yaml", tmp_path / "mp.html"
    assert main(["simulate", str(sim), "--protocol", "multipos", "--seed", "3"]) == 0
    assert main(["multipos", "--imu", str(sim), "--out", str(out), "--html", str(html),
                 "-q"]) == 0
    d = yaml.safe_load(out.read_text())
    keys = [f"{p}/{i}/{j}" for p in ("accel_matrix", "gyro_matrix", "sigma/accel_matrix")
            for i in range(3) for j in range(3)]
    keys += ["accel_bias/0", "gyro_bias/2", "residuals/accel_rms_mps2",
             "residuals/gyro_rms_rad", "diagnostics/n_static_intervals"]
    page = check_page(html.read_text(encoding="utf-8"), d,
                      ("fig-multipos-static", "fig-multipos-residuals"), keys)
    assert int(page.ids["fig-multipos-static"]["data-intervals"]) == \
        d["diagnostics"]["n_static_intervals"] == len(d["diagnostics"]["static_intervals_s"])
    res = page.ids["fig-multipos-residuals"]
    # The per-pose residuals are recomputed from the log and the result: their RMS must be
    # the fit's own.
    assert int(res["data-poses"]) == d["diagnostics"]["n_static_intervals"]
    assert float(res["data-accel-rms-mps2"]) == pytest.approx(
        d["residuals"]["accel_rms_mps2"], rel=1e-6)
    assert float(res["data-gyro-rms-rad"]) == pytest.approx(
        d["residuals"]["gyro_rms_rad"], rel=1e-6)


def test_allan_page_with_the_fitted_lines(tmp_path: Path) -> None:
    sim, out, html = tmp_path / "st", tmp_path / "noise.yaml", tmp_path / "noise.html"
    assert main(["simulate", str(sim), "--protocol", "static", "--seed", "1", "--duration",
                 "3600", "--imu-rate", "10"]) == 0
    assert main(["allan", "--imu", str(sim / "mav0" / "imu0" / "data.csv"), "--out", str(out),
                 "--html", str(html), "--allow-unresolved", "-q"]) == 0
    d = yaml.safe_load(out.read_text())
    keys = [f"per_axis/{s}/{k}/{i}" for s in ("gyroscope", "accelerometer")
            for k in ("noise_density", "random_walk", "bias_instability") for i in range(3)]
    keys += ["gyroscope_noise_density", "accelerometer_random_walk"]
    page = check_page(html.read_text(encoding="utf-8"), d,
                      ("fig-allan-gyroscope", "fig-allan-accelerometer"), keys)
    nd = [float(x) for x in page.ids["fig-allan-gyroscope"]["data-noise-density"].split(",")]
    assert nd == d["per_axis"]["gyroscope"]["noise_density"]
    assert all(math.isfinite(x) for x in nd)


# --------------------------------------------------------------------------------------------
# batch (the page the batch command writes: workflows.report_files.pages.write_batch_report)
# --------------------------------------------------------------------------------------------

def test_batch_page_lists_every_session_with_its_result(
        calibrated: tuple[dict[str, Any], str, Path], session: Path, tmp_path: Path) -> None:
    from mocap_calib.workflows.report_files.pages import write_batch_report

    d, _, _ = calibrated
    calib = session.parent / "calib.yaml"
    for sid in ("a", "b"):
        (tmp_path / sid).mkdir()
        shutil.copy(calib, tmp_path / sid / "calib.yaml")
    sessions = [{"id": "a", "imu_id": "imu1", "date": "2026-01-01", "status": "ok",
                 "result": "a/calib.yaml", "seconds": 5.1},
                {"id": "b", "imu_id": "imu1", "date": "2026-02-01", "status": "ok",
                 "result": "b/calib.yaml", "seconds": 5.3},
                {"id": "c", "imu_id": "imu2", "date": "2026-02-01", "status": "failed",
                 "error": "c/imu.csv: no such file"}]
    fleet = {"imus": {"imu1": {"sessions": [{"id": "a"}, {"id": "b"}], "latest_date": "2026-02-01",
                               "outliers": [{"id": "b", "block": "p_MI", "z": 4.2}]}}}
    out = write_batch_report(tmp_path / "batch.html", sessions, fleet)
    text = out.read_text(encoding="utf-8")
    page = check_page(text, d, ("fig-batch-trends", "s0-fig-consistency", "s1-fig-consistency"),
                      ["time_offset", "gyro_bias/0", "plausibility/verdict"])
    assert page.ids["fig-batch-trends"]["data-sessions"] == "2"
    assert "c/imu.csv: no such file" in text and "b p_MI z 4.2" in text
    assert f"{1e3 * d['time_offset']:.3f}" in text
