"""Moved to :mod:`cab_core.analysis.attempts`; kept until cab_core/apps/studio/app.py and tree.py imports it from there (issue 27)."""
from cab_core.analysis.attempts import FORKS_FOLDER, Attempt, attempt_dirs  # noqa: F401
