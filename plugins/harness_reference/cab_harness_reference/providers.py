"""This package's model providers by name. A provider's module is imported only when the provider is
built, so a missing SDK (or module) fails only when that provider is used, with the install command."""
from __future__ import annotations

import importlib
import importlib.util

from cab_core.errors import MissingDependency

_PROVIDER_MODULES = {
    "anthropic": ("anthropic_provider", "anthropic", "cab-harness-reference[anthropic]"),
    "openai": ("openai_provider", "openai", "cab-harness-reference[openai]"),
    "google": ("google_provider", "google.genai", "cab-harness-reference[google]"),
    "openai_compatible": ("openai_compatible_provider", "openai", "cab-harness-reference[openai]"),
    # any model Inspect AI can call, by its model string (.inspect_provider)
    "inspect": ("inspect_provider", "inspect_ai", "cab-harness-reference[inspect]"),
}

#: the keys of a model configuration each provider reads (``config_keys`` of its factory: cab refuses
#: any other key under ``model.`` in one line, cab_core.plugins.declared_model_keys)
_CONNECTION = {"model_id", "api_key_env", "base_url", "timeout_s", "connect_timeout_s", "retry", "max_output_tokens"}
_OPENAI = _CONNECTION | {"model", "key_env", "reasoning_effort", "extra_body"}  # the two OpenAI APIs' shared reader
CONFIG_KEYS: dict[str, frozenset[str]] = {
    "anthropic": frozenset(_CONNECTION | {"thinking", "effort"}),
    "openai": frozenset(_OPENAI | {"reasoning_summary", "cache_breakpoints", "image_detail"}),
    "google": frozenset(_CONNECTION | {"model", "key_env", "api_version", "reasoning", "thinking_budget",
                                       "include_thoughts", "temperature", "images_in_function_response",
                                       "max_images_per_request"}),
    # probe*: the capability probe of an OpenAI-compatible endpoint (.probe); label: as for inspect (an
    # Inspect eval's model bridge is such an endpoint, the configuration named by the eval's model string)
    "openai_compatible": frozenset(_OPENAI | {"max_tokens_param", "replay_reasoning", "cache_control",
                                              "probe", "probe_timeout_s", "probe_needle_tokens", "label"}),
    # model_args: Inspect's -M model arguments; generate_config: further GenerateConfig fields;
    # label: how reports name the configuration (the Inspect model string, which is no folder name)
    "inspect": frozenset({"model_id", "base_url", "api_key_env", "timeout_s", "retry", "max_output_tokens",
                          "reasoning_effort", "model_args", "generate_config", "images_in_tool_results", "label"}),
}


def _provider_factory(name: str):
    module, sdk, extra = _PROVIDER_MODULES[name]

    def factory(cfg: dict):
        # found, not imported: the provider's module imports it on its first request (0.5-2 s of start-up
        # that a sweep's plan and pre-flight, which build every configuration's provider, need not pay)
        try:
            found = importlib.util.find_spec(sdk) is not None
        except ImportError:  # its parent package is missing (google.genai)
            found = False
        if not found:
            raise MissingDependency(f"the {sdk} SDK (model provider {name!r})", f"pip install '{extra}'")
        mod = importlib.import_module(f"{__package__}.{module}")
        return mod.factory(cfg)

    factory.__name__ = f"{name}_provider_factory"
    factory.config_keys = CONFIG_KEYS[name]  # type: ignore[attr-defined]
    return factory


PROVIDERS = {name: _provider_factory(name) for name in _PROVIDER_MODULES}
