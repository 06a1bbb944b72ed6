"""Moved to :mod:`cab_core.kits.harness.stdio`; kept until cab_core/apps/cli.py imports it from there (issue 27)."""
from cab_core.kits.harness.stdio import StdioChannel, claim, claimed  # noqa: F401
