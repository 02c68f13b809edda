"""The commands' HTML report files: the pages :mod:`mocap_calib.report.html` draws (from a
result and the series computed with it), how the result was made (provenance), written
atomically; and the multi-position calibration's per-pose residuals its page shows."""
