"""Compatibility: moved to :mod:`cab_core.kits.harness.stdio` (issue 27); kept only while cab_core/apps/cli.py
imports it from this path."""
from cab_core.kits.harness.stdio import StdioChannel, claim, claimed  # noqa: F401
