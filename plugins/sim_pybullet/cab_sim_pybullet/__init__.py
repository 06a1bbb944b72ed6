"""PyBullet simulator backend plugin for cab (``cab_sim_pybullet.plugin`` is the entry point).

Importing this package does not import PyBullet; ``cab_sim_pybullet.simulator.PybulletSimulator`` does.
"""
