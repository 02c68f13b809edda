"""Rerun recordings; the only layer that imports rerun (lazily)."""
