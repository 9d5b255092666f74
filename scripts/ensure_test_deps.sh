#!/usr/bin/env bash
# The map page's test opens map.html in a real browser: Debian's headless-capable chromium.
set -euo pipefail
if command -v chromium >/dev/null 2>&1; then
  exit 0
fi
exec bash "$(dirname "$0")/apt_install.sh" chromium "the map page's browser test needs it"
