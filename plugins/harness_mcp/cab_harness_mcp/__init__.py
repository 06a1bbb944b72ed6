"""cab over the Model Context Protocol: any MCP client (Claude Code, Codex CLI, the MCP Inspector,
an SDK client) can be the agent of one attempt."""
