"""Compatibility: moved to :mod:`cab_core.attempt.engine.world` (issue 27); kept only while cab_core/testing/task_conformance.py
imports it from this path."""
from cab_core.attempt.engine.world import BuiltWorld  # noqa: F401
