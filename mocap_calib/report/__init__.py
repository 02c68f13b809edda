"""Human-readable reports of results (text tables)."""
