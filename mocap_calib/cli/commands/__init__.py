"""CLI commands, one module each; importing a module registers its command on the app."""

import importlib

COMMANDS = ("simulate", "calibrate", "diagnose", "view", "multipos", "allan", "drift", "export",
            "groundtruth", "batch")

for _name in COMMANDS:
    importlib.import_module(f"{__name__}.{_name}")
