"""Compatibility: moved to :mod:`cab_core.sweep.attempt_state` (issue 27); kept only while cab_core/apps/studio/tree.py
imports it from this path."""
from cab_core.sweep.attempt_state import SET_ASIDE, is_infrastructure_failure  # noqa: F401
