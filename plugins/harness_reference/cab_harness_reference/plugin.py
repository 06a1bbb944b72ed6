"""Registers the reference harness, its context policy and the four model providers
(:mod:`.providers`) with cab."""
from __future__ import annotations

from cab_core.contracts.hookspecs import hookimpl
from cab_core.contracts.plugin_helpers import config_dirs_hook

from .providers import PROVIDERS


def _reference_harness(cfg: dict):
    # here, not at the top: cab loads every plugin at start-up, and this import costs 1.8 s
    from .loop import ReferenceHarness  # (python -X importtime on top of cab_core.plugins, 2026-11-27)

    return ReferenceHarness(cfg)


def _reference_policy(cfg: dict):
    # here, not at the top: cab loads every plugin at start-up, and this import costs 0.12 s
    from .context import ReferenceContextPolicy  # (python -X importtime on top of cab_core.plugins, 2026-11-27)

    return ReferenceContextPolicy.from_cfg(cfg)


#: the keys of a model configuration the harness reads besides its provider's (which its provider
#: factory declares, .providers): the provider, the context policy's settings and window, pricing,
#: the published usage and the limits shared by a sweep's workers
_reference_harness.config_keys = frozenset({
    "provider", "context", "context_tokens", "pricing", "paper_usage", "limits"})


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
