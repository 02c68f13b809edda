"""File formats: EuRoC/ASL, TUM, generic CSV, result YAML."""
