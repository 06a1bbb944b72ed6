"""Compatibility: moved to :mod:`cab_core.analysis.attempts` (issue 27); kept only while cab_core/apps/studio/app.py or tree.py
imports it from this path."""
from cab_core.analysis.attempts import FORKS_FOLDER, Attempt, attempt_dirs  # noqa: F401
