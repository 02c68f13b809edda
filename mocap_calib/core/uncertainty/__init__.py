"""Does the answer hold up: segment consistency and the sensitivity to the noise model."""
