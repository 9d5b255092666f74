#!/usr/bin/env bash
# Open3D's wheel loads libusb-1.0 at import; Debian ships it as libusb-1.0-0.
set -euo pipefail
if ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "error: libusb-1.0 is missing and apt-get is not available; install libusb-1.0 with your system's package manager (Open3D needs it at import)" >&2
  exit 1
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "error: libusb-1.0 is missing; run 'apt-get install libusb-1.0-0' as root (Open3D needs it at import)" >&2
    exit 1
  fi
fi
echo "installing libusb-1.0-0 (needed by Open3D at import)"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
