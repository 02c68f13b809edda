"""Compiled kernels: they work where their cache cannot be written (read-only install, full
disk), with the same numbers."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from numba.core.caching import Cache

from mocap_calib.core.model import so3

REPO = Path(__file__).resolve().parents[1]

# A constant rate for 0.3 s: the rotation is Exp(w t) whatever the pieces (RK4 is exact for it
# up to O(h^5) per piece), the velocity of a constant specific force in the rotating frame too.
_PROBE = """
import json, sys
import numpy as np
from mocap_calib.core.model import preint
w = np.tile([0.3, -0.2, 0.5], (1, 7, 1)); f = np.zeros((1, 7, 3))
hs = np.full((1, 3), 0.1)
inc = preint.integrate_pieces(w, f, hs)
print(json.dumps({"dR": inc.dR[0].tolist(),
                  "cache": type(preint._integrate_kernel._cache).__name__}))
"""


def _probe(env: dict[str, str]) -> dict:
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                         env={**os.environ, **env}, cwd=REPO, timeout=600)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_kernels_run_without_a_writable_cache():
    """No cache location can be written (here: numba is told to use only a locator that never
    applies): the kernels compile in the process and give the same numbers."""
    cached = _probe({})
    nowhere = _probe({"NUMBA_CACHE_LOCATOR_CLASSES": "IPythonCacheLocator"})
    assert cached["cache"] == "_TolerantCache" and nowhere["cache"] == "NullCache"
    truth = so3.exp(0.3 * np.array([0.3, -0.2, 0.5]))
    np.testing.assert_allclose(nowhere["dR"], truth, atol=1e-9)
    assert nowhere["dR"] == cached["dR"]


def test_a_failed_cache_write_warns_and_the_kernel_still_runs(tmp_path, monkeypatch):
    src = tmp_path / "probe_kernel.py"
    src.write_text("from mocap_calib.core.jit import kernel\n\n\n@kernel\n"
                   "def twice(x):\n    return 2.0 * x\n")
    spec = importlib.util.spec_from_file_location("probe_kernel", src)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)

    def full_disk(self, sig, data):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Cache, "save_overload", full_disk)
    with pytest.warns(RuntimeWarning, match="not cached"):
        assert mod.twice(3.0) == 6.0


_COUNTS = """
import json, sys
from mocap_calib.core import jit
import probe_kernel
probe_kernel.twice(3.0)
print(json.dumps({"compiled": jit.compiled_in_process(), "loaded": jit.loaded_in_process()}))
"""


def test_a_process_tells_what_it_compiled_and_what_it_loaded(tmp_path):
    """The first process compiles a kernel into an empty cache, the next loads it (what
    ``compile`` reports and the check after it relies on)."""
    (tmp_path / "probe_kernel.py").write_text("from mocap_calib.core.jit import kernel\n\n\n"
                                              "@kernel\ndef twice(x):\n    return 2.0 * x\n")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "kernels"),
           "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO)])}
    runs = []
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", _COUNTS], capture_output=True, text=True,
                             env=env, timeout=600)
        assert out.returncode == 0, out.stderr
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    assert runs[0] == {"compiled": ["probe_kernel.twice"], "loaded": []}
    assert runs[1] == {"compiled": [], "loaded": ["probe_kernel.twice"]}


_PAGES = """
import json
import numpy as np
from mocap_calib.core import jit
from mocap_calib.core.model import preint

def resident():
    total, inside = 0, False
    for line in open("/proc/self/smaps"):
        head = line.split()
        if "-" in head[0] and len(head) >= 5:
            inside = len(head) > 5 and head[5].rpartition("/")[2].startswith("libllvmlite")
        elif inside and head[0] == "Rss:":
            total += int(head[1])
    return total

def run():
    w = np.tile([0.3, -0.2, 0.5], (1, 7, 1)); f = np.tile([0.0, 0.1, 9.8], (1, 7, 1))
    inc = preint.integrate_pieces(w, f, np.full((1, 3), 0.1))
    return [inc.dR.tolist(), inc.dv.tolist(), inc.dp.tolist()]

first = run()
touched = resident()
import numba
numba.njit(lambda x: x + 1.0)(1.0)  # LLVM compiles again: its code's pages come back
before = resident()
released = jit.release_compiler_pages()
after = resident()
print(json.dumps({"same": run() == first, "before": before, "after": after,
                  "released": released}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/smaps: Linux")
def test_compiler_pages_go_back_and_the_kernels_still_run():
    """The pages of LLVM's code that a run no longer needs leave the resident set (its
    relocated data stays: the process would crash without it) and the kernels give the same
    numbers afterwards."""
    out = subprocess.run([sys.executable, "-c", _PAGES], capture_output=True, text=True,
                         cwd=REPO, timeout=600)
    assert out.returncode == 0, out.stderr
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["same"]
    assert r["released"] > 50 * 2**20  # the library's code and constants
    assert r["before"] > 1024 and r["after"] < r["before"] / 2, r


_AFTER_COMPILE = """
import contextlib, io, json, sys
from mocap_calib.cli.main import main
with contextlib.redirect_stdout(io.StringIO()):
    code = main(sys.argv[1:])
from mocap_calib.core import jit
print(json.dumps({"code": code, "compiled": jit.compiled_in_process(),
                  "loaded": jit.loaded_in_process()}))
"""


@pytest.mark.slow
def test_after_compile_a_calibration_compiles_nothing(tmp_path):
    """``mocap-calib compile`` (the install step) into an empty kernel cache leaves nothing for
    a calibration to compile, so that the first run after installing is as fast as later ones.
    The session is not the one ``compile`` calibrates (other rates, length, offset and
    effects): every kernel's argument types must match a calibration's, not one run's."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "kernels")}
    out = subprocess.run([sys.executable, "-m", "mocap_calib", "compile"], capture_output=True,
                         text=True, env=env, cwd=REPO, timeout=1800)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("compiled "), out.stdout
    session = tmp_path / "session"
    sim = subprocess.run([sys.executable, "-m", "mocap_calib", "simulate", str(session),
                          "--duration", "40", "--imu-rate", "400", "--mocap-rate", "240",
                          "--seed", "5", "-e", "time_offset=-0.02", "-e", "accel_delay"],
                         capture_output=True, text=True, env=env, cwd=REPO, timeout=600)
    assert sim.returncode == 0, sim.stderr
    run = subprocess.run([sys.executable, "-c", _AFTER_COMPILE, "calibrate", str(session),
                          "--out", str(tmp_path / "calib.yaml"), "--model", "auto"],
                         capture_output=True, text=True, env=env, cwd=REPO, timeout=1800)
    assert run.returncode == 0, run.stderr
    r = json.loads(run.stdout.strip().splitlines()[-1])
    assert r["code"] == 0 and r["compiled"] == [] and len(r["loaded"]) >= 5, r
    again = subprocess.run([sys.executable, "-m", "mocap_calib", "compile"],
                           capture_output=True, text=True, env=env, cwd=REPO, timeout=1800)
    assert again.returncode == 0 and again.stdout.startswith("the kernels were cached"), \
        again.stdout
