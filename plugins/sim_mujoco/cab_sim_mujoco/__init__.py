"""MuJoCo simulator backend plugin for cab (``cab_sim_mujoco.plugin`` is the entry point).

Importing this package does not import MuJoCo; ``cab_sim_mujoco.simulator.MujocoSimulator`` does.
"""


def cab_preload() -> None:
    """The fork server's hook (``cab_core.sweep.zygote``): load the OpenGL libraries and bindings
    the workers' renderer will use, so that they are shared (:func:`cab_sim_mujoco.gl.preload`)."""
    from . import gl

    gl.preload()
