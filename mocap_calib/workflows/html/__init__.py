"""HTML reports of the commands: the figures computed for them, and how a result was made
(provenance)."""
