"""Entry point of the MuJoCo backend (group ``cab``): registers the ``mujoco`` simulator.

MuJoCo is imported only when the factory is called, so listing plugins stays cheap and a missing
MuJoCo fails with the install command.
"""
from __future__ import annotations

import cab_core
from cab_core.errors import MissingDependency


def create_simulator(cfg: dict | None = None):
    """``cfg``: ``render`` (bool), ``timestep`` (s), ``physics`` (overrides of the declared
    physical parameters); returns the simulator unbuilt."""
    try:  # here, not at the top: cab loads every plugin at start-up, and this import costs 1.6-2.2 s
        from .simulator import MujocoSimulator  # (python -X importtime, on top of cab_core and numpy)
    except ImportError as e:  # pragma: no cover - depends on the environment
        if getattr(e, "name", "") and str(e.name).split(".")[0] == "mujoco":
            raise MissingDependency("MuJoCo", "pip install 'mujoco>=3.2'") from e
        raise
    return MujocoSimulator(cfg)


@cab_core.hookimpl
def cab_simulators():
    return {"mujoco": create_simulator}


@cab_core.hookimpl
def cab_config_dirs():
    """This plugin's option files for Hydra (``conf/<group>/<option>.yaml``)."""
    return ["pkg://cab_sim_mujoco.conf"]
