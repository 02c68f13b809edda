"""CLI commands, one module each; importing a module registers its command on the app."""

import importlib

for _name in ("simulate", "calibrate", "diagnose", "view", "multipos", "allan", "drift",
              "batch"):
    try:
        importlib.import_module(f"{__name__}.{_name}")
    except ModuleNotFoundError as _err:  # a command not written yet
        if _err.name != f"{__name__}.{_name}":
            raise
