"""cab plugin: registers the ``pin`` motion planner (Pinocchio, OMPL and TOPP-RA are imported only when it is built)."""
from __future__ import annotations

from cab_core.contracts.hookspecs import hookimpl
from cab_core.contracts.plugin_helpers import config_dirs_hook

from .planner import factory


@hookimpl
def cab_planners():
    return {"pin": factory}


cab_config_dirs = config_dirs_hook("cab_planner_pin")
