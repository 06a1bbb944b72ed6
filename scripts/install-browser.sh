#!/usr/bin/env bash
# Installs the headless browser the tests drive cab's HTML pages with (tests/test_recoverability.py:
# the report's table and figure as Chromium renders them): Debian's chromium and chromium-driver
# (/usr/bin/chromium, /usr/bin/chromedriver, the same version). Selenium comes with the test extras
# (pyproject.toml). Idempotent; needs root (or sudo).
set -euo pipefail
if dpkg -s chromium >/dev/null 2>&1 && dpkg -s chromium-driver >/dev/null 2>&1; then
  echo "chromium and chromium-driver already present ($(dpkg-query -W -f='${Version}' chromium))"
  exit 0
fi
SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends chromium chromium-driver >/dev/null
echo "installed: chromium and chromium-driver $(dpkg-query -W -f='${Version}' chromium)"
