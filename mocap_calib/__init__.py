"""mocap-calib: calibrate an IMU from motion-capture sessions.

Layers: ``core`` (estimation, no file formats, CLI or viewer), ``io`` (file formats), ``sim``
(simulated sessions with known truth), ``viz`` (rerun recordings, imported lazily) and ``cli``.
"""

import time as _time

__version__ = "0.1.0"
#: When the package was first imported: a command's start-up (its imports) is measured from
#: here (the result's ``solver.step_seconds.startup``).
IMPORTED_AT = _time.perf_counter()
