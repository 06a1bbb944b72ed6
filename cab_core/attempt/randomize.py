"""Moved to :mod:`cab_core.attempt.variation.randomize`; kept until cab_core/attempt/spec.py imports it from there (issue 27)."""
from cab_core.attempt.variation.randomize import Randomization  # noqa: F401
