#!/bin/sh
# Debian/Ubuntu packages the viewer needs to render with VTK (>= 9.4 wheels dlopen their GL).
# Idempotent: installs only what is missing (needs root or sudo then), does nothing otherwise.
#
#   headless (CI, servers: the EGL backend, Mesa's llvmpipe software renderer)
#     libegl1          libEGL.so.1 (glvnd dispatch)
#     libegl-mesa0     Mesa's EGL vendor library (surfaceless/device platforms)
#     libgl1-mesa-dri  the DRI drivers, among them swrast/llvmpipe
#   desktop (an X display: the x11 backend, interactive windows)
#     libgl1 libglx-mesa0   libGL.so.1 + Mesa's GLX vendor library
#     libx11-6 libxcursor1  opened by VTK's libvtkx11 at run time
#
# Not needed: libosmesa6 and xvfb (the viewer falls back to them when EGL is missing, see
# viewer/backend.py; set ARSURF_GL_FALLBACKS=1 to install them too).
set -e
PKGS="libegl1 libegl-mesa0 libgl1-mesa-dri libgl1 libglx-mesa0 libx11-6 libxcursor1"
[ "${ARSURF_GL_FALLBACKS:-0}" = 1 ] && PKGS="$PKGS libosmesa6 xvfb"
command -v dpkg-query >/dev/null 2>&1 || { echo "not a Debian system: install EGL + Mesa (or run under a display) yourself"; exit 0; }
missing=""
for p in $PKGS; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
[ -z "$missing" ] && exit 0
echo "installing Debian packages for rendering:$missing"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null 2>&1 || { echo "need root (or sudo) to install:$missing"; exit 1; }
    SUDO=sudo
fi
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
