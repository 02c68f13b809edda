"""Estimation core: knows nothing of files, the CLI or the viewer."""
