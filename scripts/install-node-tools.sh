#!/usr/bin/env bash
# Installs the Node tools the tests drive cab with: the MCP Inspector CLI
# (@modelcontextprotocol/inspector, which needs Node >= 22.19) and a Node 22 runtime for it, both
# from the npm registry into .cab_cache/node-tools (nothing global). Needs npm: installs Debian's
# nodejs/npm when it is missing. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
INSPECTOR_VERSION=2.12.0
NODE_VERSION=22
DEST=.cab_cache/node-tools
if ! command -v npm >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends nodejs npm >/dev/null
fi
have=$(cd "$DEST" 2>/dev/null && node -p "require('./node_modules/@modelcontextprotocol/inspector/package.json').version" 2>/dev/null || true)
if [ "$have" = "$INSPECTOR_VERSION" ] && [ -x "$DEST/node_modules/.bin/node" ]; then
  echo "MCP Inspector $have already in $DEST"
  exit 0
fi
mkdir -p "$DEST"
npm install --prefix "$DEST" --no-audit --no-fund --loglevel=error \
  "node@$NODE_VERSION" "@modelcontextprotocol/inspector@$INSPECTOR_VERSION" >/dev/null
echo "MCP Inspector $INSPECTOR_VERSION with node $("$DEST/node_modules/.bin/node" --version) in $DEST"
