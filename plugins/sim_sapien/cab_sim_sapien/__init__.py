"""SAPIEN 3 simulator backend plugin for cab (``cab_sim_sapien.plugin`` is the entry point).

Importing this package does not import SAPIEN; ``cab_sim_sapien.simulator.SapienSimulator`` does.
"""


def cab_preload() -> None:
    """The fork server's hook (``cab_core.sweep.zygote``): load the Vulkan loader and Mesa's Vulkan
    drivers the workers' renderer will use, so that they are shared
    (:func:`cab_sim_sapien.renderer.preload`)."""
    from . import renderer

    renderer.preload()
