#!/usr/bin/env bash
# Installs the Node tools the tests drive cab with, from the npm registry into .cab_cache/node-tools
# (nothing global): a Node 22 runtime, the MCP Inspector CLI (@modelcontextprotocol/inspector, which
# needs Node >= 22.19), and the two vendor CLIs at the versions the paper pins (model configs
# opus5_claude_code and astra_codex): Claude Code (needs Node >= 22; its npm package installs a
# native binary for the platform) and Codex CLI (a Node launcher for its native binary). Needs npm:
# installs Debian's nodejs/npm when it is missing. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
NODE_VERSION=22
INSPECTOR_VERSION=2.12.0
CLAUDE_CODE_VERSION=2.1.212
CODEX_VERSION=0.154.0
DEST=.cab_cache/node-tools
if ! command -v npm >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends nodejs npm >/dev/null
fi
installed() {  # the version of an npm package installed in $DEST, or nothing
  (cd "$DEST" 2>/dev/null && node -p "require('./node_modules/$1/package.json').version" 2>/dev/null) || true
}
if [ "$(installed @modelcontextprotocol/inspector)" = "$INSPECTOR_VERSION" ] \
   && [ "$(installed @anthropic-ai/claude-code)" = "$CLAUDE_CODE_VERSION" ] \
   && [ "$(installed @openai/codex)" = "$CODEX_VERSION" ] \
   && [ -x "$DEST/node_modules/.bin/node" ] && [ -x "$DEST/node_modules/.bin/claude" ] && [ -x "$DEST/node_modules/.bin/codex" ]; then
  echo "MCP Inspector $INSPECTOR_VERSION, Claude Code $CLAUDE_CODE_VERSION and Codex CLI $CODEX_VERSION already in $DEST"
  exit 0
fi
mkdir -p "$DEST"
npm install --prefix "$DEST" --save-exact --no-audit --no-fund --loglevel=error \
  "node@$NODE_VERSION" "@modelcontextprotocol/inspector@$INSPECTOR_VERSION" \
  "@anthropic-ai/claude-code@$CLAUDE_CODE_VERSION" "@openai/codex@$CODEX_VERSION" >/dev/null
echo "node $("$DEST/node_modules/.bin/node" --version), MCP Inspector $INSPECTOR_VERSION," \
     "Claude Code $("$DEST/node_modules/.bin/claude" --version), $("$DEST/node_modules/.bin/codex" --version) in $DEST"
