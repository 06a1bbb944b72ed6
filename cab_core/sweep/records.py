"""Moved to :mod:`cab_core.sweep.attempt_state`; kept until cab_core/apps/studio/tree.py imports it from there (issue 27)."""
from cab_core.sweep.attempt_state import SET_ASIDE, is_infrastructure_failure  # noqa: F401
