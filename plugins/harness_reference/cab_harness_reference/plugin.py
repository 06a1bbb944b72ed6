"""Registers the reference harness, its context policy and the four model providers
(:mod:`.providers`) with cab."""
from __future__ import annotations

from cab_core.contracts.hookspecs import hookimpl
from cab_core.contracts.plugin_helpers import config_dirs_hook

from .providers import PROVIDERS


def _reference_harness(cfg: dict):
    from .loop import ReferenceHarness

    return ReferenceHarness(cfg)


def _reference_policy(cfg: dict):
    from .context import ReferenceContextPolicy

    return ReferenceContextPolicy.from_cfg(cfg)


@hookimpl
def cab_harnesses():
    return {"reference": _reference_harness}


@hookimpl
def cab_model_providers():
    return dict(PROVIDERS)


@hookimpl
def cab_context_policies():
    return {"reference": _reference_policy}


cab_config_dirs = config_dirs_hook("cab_harness_reference")
