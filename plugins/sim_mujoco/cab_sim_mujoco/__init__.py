"""MuJoCo simulator backend plugin for cab (``cab_sim_mujoco.plugin`` is the entry point).

Importing this package does not import MuJoCo; ``cab_sim_mujoco.simulator.MujocoSimulator`` does.
"""
