"""The harness kit: what a model harness plugin builds on (the prompt and image rules, pricing, the
agent block of a record, the conversation rebuild, the tool-response type and the stdio channel)."""
