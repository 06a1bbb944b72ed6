"""cab plugin: registers the ``mplib`` motion planner (mplib is imported only when it is built)."""
from __future__ import annotations

import cab_core

from .planner import factory


@cab_core.hookimpl
def cab_planners():
    return {"mplib": factory}


@cab_core.hookimpl
def cab_config_dirs():
    """This plugin's option files for Hydra (``conf/<group>/<option>.yaml``)."""
    return ["pkg://cab_planner_mplib.conf"]
