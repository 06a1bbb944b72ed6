"""Entry point of the SAPIEN backend (group ``cab``): registers the ``sapien`` simulator.

SAPIEN is imported only when the factory is called, so listing plugins stays cheap and a missing
SAPIEN fails with the install command.
"""
from __future__ import annotations

import cab_core
from cab_core.errors import MissingDependency


def create_simulator(cfg: dict | None = None):
    """``cfg``: ``render`` (bool), ``timestep`` (s), ``shader``, ``shadows``; returns it unbuilt."""
    try:  # here, not at the top: cab loads every plugin at start-up, and this import costs 6.8-7.3 s
        from .simulator import SapienSimulator  # (python -X importtime, on top of cab_core and numpy)
    except ImportError as e:  # pragma: no cover - depends on the environment
        if getattr(e, "name", "") and str(e.name).split(".")[0] == "sapien":
            raise MissingDependency("SAPIEN 3", "pip install 'sapien==3.0.3'") from e
        raise
    return SapienSimulator(cfg)


@cab_core.hookimpl
def cab_simulators():
    return {"sapien": create_simulator}


@cab_core.hookimpl
def cab_config_dirs():
    """This plugin's option files for Hydra (``conf/<group>/<option>.yaml``)."""
    return ["pkg://cab_sim_sapien.conf"]
