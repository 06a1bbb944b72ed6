"""Moved to :mod:`cab_core.attempt.engine.human`; kept until cab_core/apps/studio/child.py and play.py imports it from there (issue 27)."""
from cab_core.attempt.engine.human import SESSIONS, ChildBridge, PlayBridge, crash_error  # noqa: F401
