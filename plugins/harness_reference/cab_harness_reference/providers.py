"""This package's model providers by name. A provider's module is imported only when the provider is
built, so a missing SDK (or module) fails only when that provider is used, with the install command."""
from __future__ import annotations

import importlib

from cab_core.errors import MissingDependency

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
