"""pandas for the CSV readers, imported without pyarrow.

pandas imports pyarrow whenever it is installed (rerun-sdk brings it), which costs ~65 MB of
resident memory in every run; the readers use only pandas' own C parser and object/str columns.
Hidden while pandas imports, pyarrow stays importable for whoever needs it later (the rerun
recording); pandas then keeps its python-backed string dtype. Measured on a 60-min, 200 Hz IMU
CSV: 0.89 -> 1.04 s to read, 332 -> 240 MB resident after reading.
"""

from __future__ import annotations

import sys
from types import ModuleType


def _import_pandas() -> ModuleType:
    if "pandas" in sys.modules or "pyarrow" in sys.modules:
        import pandas
        return pandas
    sys.modules["pyarrow"] = None  # type: ignore[assignment]  # makes `import pyarrow` fail
    try:
        import pandas
    finally:
        del sys.modules["pyarrow"]
    return pandas


pd = _import_pandas()
