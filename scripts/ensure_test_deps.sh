#!/usr/bin/env bash
# The map page's test opens map.html in a real browser: Debian's headless-capable chromium.
set -euo pipefail
if command -v chromium >/dev/null 2>&1; then
  exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "error: chromium is missing and apt-get is not available; install chromium with your system's package manager (the map page's browser test needs it)" >&2
  exit 1
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "error: chromium is missing; run 'apt-get install chromium' as root (the map page's browser test needs it)" >&2
    exit 1
  fi
fi
echo "installing chromium (the map page's browser test)"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium >/dev/null
