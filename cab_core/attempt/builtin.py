"""Moved to :mod:`cab_core.attempt.engine.builtin`; kept until pyproject.toml's entry point `core` imports it from there (issue 27)."""
from cab_core.attempt.engine.builtin import cab_agents, cab_harnesses  # noqa: F401
