"""Entry point of the MuJoCo backend (group ``cab``): registers the ``mujoco`` simulator.

MuJoCo is imported only when the factory is called, so listing plugins stays cheap and a missing
MuJoCo fails with the install command.
"""
from __future__ import annotations

from cab_core.contracts.hookspecs import hookimpl
from cab_core.contracts.plugin_helpers import config_dirs_hook, missing_dependency


def create_simulator(cfg: dict | None = None):
    """``cfg``: ``render`` (bool), ``timestep`` (s), ``physics`` (overrides of the declared
    physical parameters); returns the simulator unbuilt."""
    with missing_dependency("MuJoCo", "pip install 'mujoco>=3.2'", "mujoco"):
        # here, not at the top: cab loads every plugin at start-up, and this import costs 1.6-2.2 s
        from .simulator import MujocoSimulator  # (python -X importtime, on top of cab_core and numpy)
    return MujocoSimulator(cfg)


@hookimpl
def cab_simulators():
    return {"mujoco": create_simulator}


cab_config_dirs = config_dirs_hook("cab_sim_mujoco")
