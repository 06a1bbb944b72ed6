"""Kits for the people who extend cab: what a task suite (``cab_core.kits.task``, its oracle helpers)
and a model harness (``cab_core.kits.harness``) import, apart from the engine's internals and from
any one suite. With ``cab_core.contracts``, ``cab_core.errors`` and ``cab_core.geometry`` they are
the public surface a plugin builds on (docs/plugins.md)."""
