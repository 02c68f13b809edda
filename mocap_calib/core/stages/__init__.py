"""Stages 1-2: attitude and velocity factors on keyframe intervals (the position stage's start
values)."""
