#!/usr/bin/env bash
# Open3D's wheel loads libusb-1.0 at import; Debian ships it as libusb-1.0-0.
set -euo pipefail
if ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  exit 0
fi
exec bash "$(dirname "$0")/apt_install.sh" libusb-1.0-0 "needed by Open3D at import"
