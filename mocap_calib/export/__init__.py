"""Exporters: calibration results in other tools' file formats."""
