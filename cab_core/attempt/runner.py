"""Compatibility: moved to :mod:`cab_core.attempt.engine.runner` (issue 27); kept only while cab_core/apps/cli.py or cab_core/apps/studio/child.py
imports it from this path."""
from cab_core.attempt.engine.runner import attempt_spec, run_attempt  # noqa: F401
