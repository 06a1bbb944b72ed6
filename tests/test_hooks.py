"""Every hook declared in cab_core.contracts.hookspecs has a caller: the registration hooks through
``cab_core.plugins.registry``/``create``; model providers and context policies are created by name
by the harness that talks to a model."""
import types

import pytest

from cab_core import hookimpl
from cab_core.contracts import hookspecs
from cab_core.plugins import KINDS, build_plugin_manager, registry


def test_every_declared_hook_is_a_registry_kind():
    declared = {n for n in dir(hookspecs) if n.startswith("cab_") and callable(getattr(hookspecs, n))}
    # cab_config_dirs: Hydra search paths, read by the config loader rather than a registry
    assert declared - {"cab_config_dirs"} == {f"cab_{k}" for k in KINDS}
    pm = build_plugin_manager(autoload=False)
    for kind in KINDS:
        assert registry(kind, pm) == {}


class FakeProvider:
    def __init__(self, cfg):
        self.cfg = cfg
        self.checked = 0

    def check_credentials(self):
        self.checked += 1


@pytest.fixture
def third_party(process_plugins):
    """A third party's provider and context policy, installed in the process's plugin manager."""
    made = {}
    mod = types.ModuleType("third_party")
    mod.cab_model_providers = hookimpl(lambda: {"my_api": lambda cfg: made.setdefault("provider", FakeProvider(cfg))})
    mod.cab_context_policies = hookimpl(lambda: {"my_policy": lambda cfg: made.setdefault("policy", ("P", cfg))})
    process_plugins(mod, "third_party")
    return made


def test_a_model_harness_creates_providers_and_policies_by_name(third_party):
    pytest.importorskip("cab_harness_reference")
    from cab_harness_reference.loop import ReferenceHarness  # after the skip: the plugin may not be installed

    h = ReferenceHarness({})
    model_cfg = {"name": "m", "provider": "my_api", "context": {"policy": "my_policy", "keep": 3}}
    h.preflight(model_cfg)
    assert h.provider is third_party["provider"] and h.provider.checked == 1
    assert h.provider.cfg == model_cfg
    assert h._policy(model_cfg) == ("P", {"keep": 3})
