"""Moved to :mod:`cab_core.attempt.variation.perturb`; kept until cab_core/attempt/spec.py imports it from there (issue 27)."""
from cab_core.attempt.variation.perturb import Perturbation  # noqa: F401
