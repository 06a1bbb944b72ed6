"""Compatibility: moved to :mod:`cab_core.attempt.variation.perturb` (issue 27); kept only while cab_core/attempt/spec.py
imports it from this path."""
from cab_core.attempt.variation.perturb import Perturbation  # noqa: F401
