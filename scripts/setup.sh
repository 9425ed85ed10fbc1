#!/usr/bin/env bash
# Installs lumiprobe's system dependencies (Debian 12) and builds it in release mode.
set -euo pipefail
cd "$(dirname "$0")/.."
need=()
for pkg in pkg-config libopencv-dev libopencv-contrib-dev g++ colmap ffmpeg blender python3-numpy python3-opencv chromium; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO=sudo
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}"
fi
# The real clients the tests read lumiprobe's engine files with (npm ktx-parse).
if ! command -v npm >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO=sudo
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends nodejs npm
fi
{ [ -d tools/js/node_modules/ktx-parse ] && [ -d tools/js/node_modules/three ]; } || npm ci --prefix tools/js --no-audit --no-fund
cargo build --release --locked 2>/dev/null || cargo build --release
