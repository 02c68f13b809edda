"""mocap-calib: calibrate an IMU from motion-capture sessions.

Layers: ``core`` (estimation, no file formats, CLI or viewer), ``io`` (file formats), ``sim``
(simulated sessions with known truth), ``viz`` (rerun recordings, imported lazily) and ``cli``.
"""

__version__ = "0.1.0"
