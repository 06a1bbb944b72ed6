"""SAPIEN backend plugin."""
