"""cab plugin: registers the ``aloha_agilex`` embodiment."""
from __future__ import annotations

import cab_core

from .embodiment import factory


@cab_core.hookimpl
def cab_embodiments():
    return {"aloha_agilex": factory}


@cab_core.hookimpl
def cab_config_dirs():
    """This plugin's option files for Hydra (``conf/<group>/<option>.yaml``)."""
    return ["pkg://cab_embodiment_aloha.conf"]
