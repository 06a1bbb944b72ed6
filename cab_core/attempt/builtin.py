"""Compatibility: moved to :mod:`cab_core.attempt.engine.builtin` (issue 27); kept only while pyproject.toml's entry point `core`
imports it from this path."""
from cab_core.attempt.engine.builtin import cab_agents, cab_harnesses  # noqa: F401
