"""cab's Hydra launcher for sweeps on one machine (local_launcher)."""
