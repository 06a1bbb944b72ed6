"""The contracts: what a plugin implements and what a task is written with. Simulator, planner,
embodiment, scene description, task and verifier, the checkpoint vocabulary, the plugin hooks, and
the validation helpers every simulator applies alike. Nothing here runs an attempt."""
