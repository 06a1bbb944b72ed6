"""cab plugin: registers the ``mplib`` motion planner (mplib is imported only when it is built)."""
from __future__ import annotations

from cab_core.contracts.hookspecs import hookimpl
from cab_core.contracts.plugin_helpers import config_dirs_hook

from .planner import factory


@hookimpl
def cab_planners():
    return {"mplib": factory}


cab_config_dirs = config_dirs_hook("cab_planner_mplib")
