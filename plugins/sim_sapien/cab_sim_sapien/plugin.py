"""Entry point of the SAPIEN backend (group ``cab``): registers the ``sapien`` simulator.

SAPIEN is imported only when the factory is called, so listing plugins stays cheap and a missing
SAPIEN fails with the install command.
"""
from __future__ import annotations

from cab_core.contracts.hookspecs import hookimpl
from cab_core.contracts.plugin_helpers import config_dirs_hook, missing_dependency


def create_simulator(cfg: dict | None = None):
    """``cfg``: ``render`` (bool), ``timestep`` (s), ``shader``, ``shadows``; returns it unbuilt."""
    with missing_dependency("SAPIEN 3", "pip install 'sapien==3.0.3'", "sapien"):
        # here, not at the top: cab loads every plugin at start-up, and this import costs 6.8-7.3 s
        from .simulator import SapienSimulator  # (python -X importtime, on top of cab_core and numpy)
    return SapienSimulator(cfg)


@hookimpl
def cab_simulators():
    return {"sapien": create_simulator}


cab_config_dirs = config_dirs_hook("cab_sim_sapien")
