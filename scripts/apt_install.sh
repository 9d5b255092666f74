#!/usr/bin/env bash
# apt_install.sh PACKAGE WHY: install a Debian package (as root, or through sudo), or say how.
set -euo pipefail
package="$1"
why="$2"
if ! command -v apt-get >/dev/null 2>&1; then
  echo "error: $package is missing and apt-get is not available; install it with your system's package manager ($why)" >&2
  exit 1
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then SUDO="sudo"; else
    echo "error: $package is missing; run 'apt-get install $package' as root ($why)" >&2
    exit 1
  fi
fi
echo "installing $package ($why)"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "$package" >/dev/null
