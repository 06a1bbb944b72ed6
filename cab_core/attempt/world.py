"""Moved to :mod:`cab_core.attempt.engine.world`; kept until cab_core/testing/task_conformance.py imports it from there (issue 27)."""
from cab_core.attempt.engine.world import BuiltWorld  # noqa: F401
