"""cab plugin: registers the ``aloha_agilex`` embodiment."""
from __future__ import annotations

from cab_core.contracts.hookspecs import hookimpl
from cab_core.contracts.plugin_helpers import config_dirs_hook

from .embodiment import factory


@hookimpl
def cab_embodiments():
    return {"aloha_agilex": factory}


cab_config_dirs = config_dirs_hook("cab_embodiment_aloha")
