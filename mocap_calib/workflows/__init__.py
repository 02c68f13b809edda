"""Library functions behind the CLI commands: read inputs, run the core, return results."""
