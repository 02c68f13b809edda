"""Checks on the answer: what the motion leaves undetermined, plausibility, the effects the
model lacks, and the verdict."""
