#!/usr/bin/env bash
# What the tests need from Debian: chromium (the map page's test opens map.html in a real
# browser) and iproute2 (the two-host tests join network namespaces with `ip netns`).
set -euo pipefail
here="$(dirname "$0")"
if ! command -v chromium >/dev/null 2>&1; then
  bash "$here/apt_install.sh" chromium "the map page's browser test needs it"
fi
if ! command -v ip >/dev/null 2>&1; then
  bash "$here/apt_install.sh" iproute2 "the two-host tests need ip netns"
fi
