#!/bin/sh
# Debian packages arsurf needs for offscreen rendering (VTK via Mesa). Idempotent: does nothing
# when they are already there; needs root (or sudo) only when something is missing.
set -e
PKGS="libgl1 libglx-mesa0 libegl1 libosmesa6 libxrender1 libxext6 libx11-6 xvfb"
missing=""
for p in $PKGS; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
[ -z "$missing" ] && exit 0
echo "installing Debian packages for offscreen rendering:$missing"
SUDO=""
[ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && SUDO=sudo
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
