"""One attempt, from a composed configuration to its finished record: building the world, serving
the agent's calls under budgets, scoring with the hidden verifier, recording; and replaying one."""
