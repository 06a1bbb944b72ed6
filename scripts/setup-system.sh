#!/usr/bin/env bash
# Installs the system packages cab needs on Debian 12 (bookworm): the CPU Vulkan stack that SAPIEN
# renders through (Mesa lavapipe >= 24.3 from bookworm-backports), bubblewrap for the run_code
# sandbox, ffmpeg for videos. Idempotent; needs root (or sudo).
set -euo pipefail
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
need=0
for pkg in bubblewrap libvulkan1 ffmpeg libegl1 libgl1; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need=1
done
mesa_ver=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || echo none)
case "$mesa_ver" in 2[4-9].*|3*) ;; *) need=1 ;; esac
if [ "$need" -eq 0 ]; then echo "system packages already present (mesa-vulkan-drivers $mesa_ver)"; exit 0; fi
if [ -r /etc/os-release ] && grep -q 'VERSION_CODENAME=bookworm' /etc/os-release; then
  if ! grep -rqs 'bookworm-backports' /etc/apt/sources.list /etc/apt/sources.list.d/; then
    echo "deb http://deb.debian.org/debian bookworm-backports main" | $SUDO tee /etc/apt/sources.list.d/cab-backports.list >/dev/null
  fi
  BP="-t bookworm-backports"
else
  BP=""
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends $BP mesa-vulkan-drivers libvulkan1 libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri >/dev/null
$SUDO apt-get install -y -qq --no-install-recommends bubblewrap ffmpeg vulkan-tools >/dev/null
echo "installed: mesa-vulkan-drivers $(dpkg-query -W -f='${Version}' mesa-vulkan-drivers), bubblewrap, ffmpeg"
