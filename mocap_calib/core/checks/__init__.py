"""Checks on the answer and its inputs: conventions, degenerate motion, plausibility, and the
verdict."""
