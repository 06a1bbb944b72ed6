"""Pinocchio + OMPL + TOPP-RA planner plugin."""
