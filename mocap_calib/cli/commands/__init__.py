"""CLI commands, one module each; importing a module registers its command on the app."""

import importlib

COMMANDS = ("simulate", "calibrate", "diagnose", "view", "multipos", "allan", "drift", "export",
            "groundtruth", "batch", "compile")


def register(names: tuple[str, ...] = COMMANDS) -> None:
    """Register the commands ``names`` (importing a command's module imports what it runs:
    a run registers only its own command, so that it does not pay for every other's imports)."""
    for name in names:
        importlib.import_module(f"{__name__}.{name}")
