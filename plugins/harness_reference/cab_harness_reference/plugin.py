"""Registers the reference harness, its context policy and the four model providers with cab.
Provider modules are imported only when a provider is built, so a missing SDK (or module) fails
only when that provider is used, with the install command."""
from __future__ import annotations

import importlib

from cab_core.errors import MissingDependency
from cab_core.contracts.hookspecs import hookimpl

_PROVIDER_MODULES = {
    "anthropic": ("anthropic_provider", "anthropic", "cab-harness-reference[anthropic]"),
    "openai": ("openai_provider", "openai", "cab-harness-reference[openai]"),
    "google": ("google_provider", "google.genai", "cab-harness-reference[google]"),
    "openai_compatible": ("openai_compatible_provider", "openai", "cab-harness-reference[openai]"),
}


def _provider_factory(name: str):
    module, sdk, extra = _PROVIDER_MODULES[name]

    def factory(cfg: dict):
        try:
            importlib.import_module(sdk)
        except ImportError:
            raise MissingDependency(f"the {sdk} SDK (model provider {name!r})", f"pip install '{extra}'") from None
        mod = importlib.import_module(f"{__package__}.{module}")
        return mod.factory(cfg)

    factory.__name__ = f"{name}_provider_factory"
    return factory


PROVIDERS = {name: _provider_factory(name) for name in _PROVIDER_MODULES}


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


@hookimpl
def cab_config_dirs():
    """This plugin's option files for Hydra (``conf/<group>/<option>.yaml``)."""
    return ["pkg://cab_harness_reference.conf"]
