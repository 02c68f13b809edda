"""Compiled kernels: they work where their cache cannot be written (read-only install, full
disk), with the same numbers."""

from __future__ import annotations

import importlib.util
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
    import json

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
