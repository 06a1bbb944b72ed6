"""The cab project's own Hydra composition (installed as ``cab_conf`` from the checkout's ``conf/``):
its primary config, which replaces the core's, and its experiments. Data only."""
