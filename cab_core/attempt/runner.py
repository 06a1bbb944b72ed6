"""Moved to :mod:`cab_core.attempt.engine.runner`; kept until cab_core/apps/cli.py and cab_core/apps/studio/child.py imports it from there (issue 27)."""
from cab_core.attempt.engine.runner import attempt_spec, run_attempt  # noqa: F401
