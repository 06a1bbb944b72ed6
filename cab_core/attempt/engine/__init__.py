"""The engine of one attempt: the world built, the agent's calls served under budgets, the verdict
and the checkpoints decided, the runner that drives a harness through it, the core's own agents."""
