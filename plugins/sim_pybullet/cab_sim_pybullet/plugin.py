"""Entry point of the PyBullet backend (group ``cab``): registers the ``pybullet`` simulator.

PyBullet is imported only when the factory is called, so listing plugins stays cheap and a missing
PyBullet fails with the install command.
"""
from __future__ import annotations

import cab_core
from cab_core.errors import MissingDependency


def create_simulator(cfg: dict | None = None):
    """``cfg``: ``render``, ``renderer``, ``timestep``, ``physics``; returns it unbuilt."""
    try:  # here, not at the top: cab loads every plugin at start-up, and this import costs 2.5-3.2 s
        from .simulator import PybulletSimulator  # (python -X importtime, on top of cab_core and numpy)
    except ImportError as e:  # pragma: no cover - depends on the environment
        if getattr(e, "name", "") and str(e.name).split(".")[0] in ("pybullet", "pybullet_utils", "scipy"):
            raise MissingDependency("PyBullet", "pip install 'pybullet==3.2.7' scipy") from e
        raise
    return PybulletSimulator(cfg)


@cab_core.hookimpl
def cab_simulators():
    return {"pybullet": create_simulator}


@cab_core.hookimpl
def cab_config_dirs():
    """This plugin's option files for Hydra (``conf/<group>/<option>.yaml``)."""
    return ["pkg://cab_sim_pybullet.conf"]
