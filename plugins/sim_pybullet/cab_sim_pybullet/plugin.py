"""Entry point of the PyBullet backend (group ``cab``): registers the ``pybullet`` simulator.

PyBullet is imported only when the factory is called, so listing plugins stays cheap and a missing
PyBullet fails with the install command.
"""
from __future__ import annotations

from cab_core.contracts.hookspecs import hookimpl
from cab_core.contracts.plugin_helpers import config_dirs_hook, missing_dependency


def create_simulator(cfg: dict | None = None):
    """``cfg``: ``render``, ``renderer``, ``timestep``, ``physics``; returns it unbuilt."""
    with missing_dependency("PyBullet", "pip install 'pybullet==3.2.7' scipy", "pybullet", "pybullet_utils", "scipy"):
        # here, not at the top: cab loads every plugin at start-up, and this import costs 2.5-3.2 s
        from .simulator import PybulletSimulator  # (python -X importtime, on top of cab_core and numpy)
    return PybulletSimulator(cfg)


@hookimpl
def cab_simulators():
    return {"pybullet": create_simulator}


cab_config_dirs = config_dirs_hook("cab_sim_pybullet")
