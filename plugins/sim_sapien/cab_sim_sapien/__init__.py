"""SAPIEN 3 simulator backend plugin for cab (``cab_sim_sapien.plugin`` is the entry point).

Importing this package does not import SAPIEN; ``cab_sim_sapien.simulator.SapienSimulator`` does.
"""
