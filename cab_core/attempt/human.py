"""Compatibility: moved to :mod:`cab_core.attempt.engine.human` (issue 27); kept only while cab_core/apps/studio/child.py or play.py
imports it from this path."""
from cab_core.attempt.engine.human import SESSIONS, ChildBridge, PlayBridge, crash_error  # noqa: F401
