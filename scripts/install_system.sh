#!/usr/bin/env bash
# The system packages pip cannot install, for scripts/install.sh: the libraries open3d and pymeshlab load that a
# minimal Debian lacks (libusb-1.0, libEGL, libGL, libOpenGL; ns-export, agrinerf-export)
# and, with --dev, Chromium (the viewer test, tests/test_viewer.py).
#   bash scripts/install_system.sh [--dev]
# As root on a system with apt-get (Debian/Ubuntu) it installs what is missing. Otherwise, or when apt-get fails, it
# says what to run and exits 1 (the plugin installs and trains without them; only the commands named need them).
set -euo pipefail
DEV=0
for arg in "$@"; do
  case "$arg" in
    --dev) DEV=1 ;;
    *) echo "install_system.sh: unknown option '$arg' (use --dev)" >&2; exit 2 ;;
  esac
done

missing=()
why=()
# soname:Debian package:the module that loads it, agrinerf_ns/system_deps.py's SYSTEM_LIBRARIES (this script runs
# without the venv; tests/test_install_system.py keeps the two equal): whichever package brought each, as the dynamic
# loader finds it (ldconfig's cache; /sbin may be off PATH)
LDCONFIG=$(command -v ldconfig || echo /sbin/ldconfig)
ldcache=$("$LDCONFIG" -p 2>/dev/null || true)
for entry in libusb-1.0.so.0:libusb-1.0-0:open3d libEGL.so.1:libegl1:open3d libGL.so.1:libgl1:open3d \
  libOpenGL.so.0:libopengl0:pymeshlab; do
  IFS=: read -r soname package user <<< "$entry"
  case "$ldcache" in
    *"$soname"*) ;;
    *) missing+=("$package"); why+=("$package ($user: ns-export)") ;;
  esac
done
# Chromium: looked up as tests/test_viewer.py does
if [ "$DEV" = 1 ] && ! command -v chromium >/dev/null && ! command -v chromium-browser >/dev/null; then
  missing+=(chromium); why+=("chromium (the viewer test)")
fi
[ "${#missing[@]}" -eq 0 ] && exit 0

if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
  echo "install_system.sh: installing ${why[*]} with apt-get" >&2
  if apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"
  then
    exit 0
  fi
  echo "install_system.sh: apt-get could not install ${missing[*]}; run 'apt-get install ${missing[*]}' when it can" >&2
elif command -v apt-get >/dev/null; then
  echo "install_system.sh: missing ${why[*]}: run 'sudo apt-get install ${missing[*]}'" >&2
else
  echo "install_system.sh: missing ${why[*]}: install them with the system's package manager" \
    "(Fedora: libusb1, libglvnd-egl, libglvnd-glx, libglvnd-opengl)" >&2
fi
exit 1
