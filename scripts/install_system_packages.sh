#!/usr/bin/env bash
# System libraries that softforce's wheels load at run time, installed only if missing:
#   libusb-1.0-0   open3d and pyrealsense2 (USB access to RealSense cameras)
#   libgl1 libgomp1 libx11-6           open3d's rendering and OpenMP
#   libglu1-mesa libxrender1 libxcursor1 libxft2 libxinerama1   gmsh's shared library
# and, optionally, Debian's chromium: the headless browser of the report's browser test
# (tests/test_report_browser.py). Without it the setup goes on and that test skips.
set -euo pipefail
packages=(libusb-1.0-0 libgl1 libgomp1 libx11-6 libglu1-mesa libxrender1 libxcursor1 libxft2
          libxinerama1)
missing=()
for package in "${packages[@]}"; do
  dpkg -s "$package" >/dev/null 2>&1 || missing+=("$package")
done
sudo=""
[ "$(id -u)" -ne 0 ] && command -v sudo >/dev/null 2>&1 && sudo="sudo"
can_install() { command -v apt-get >/dev/null 2>&1 && { [ "$(id -u)" -eq 0 ] || [ -n "$sudo" ]; }; }

if [ ${#missing[@]} -gt 0 ]; then
  if ! command -v apt-get >/dev/null 2>&1; then
    echo "softforce setup: missing system libraries ${missing[*]} and no apt-get; install them" \
         "with your package manager" >&2
    exit 1
  fi
  can_install || {
    echo "softforce setup: run as root or install sudo to get ${missing[*]}" >&2; exit 1; }
  echo "softforce setup: installing ${missing[*]}" >&2
  $sudo apt-get update -qq || true
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}" >/dev/null
fi

if ! command -v chromium >/dev/null 2>&1 && ! command -v chromium-browser >/dev/null 2>&1; then
  if can_install && { $sudo apt-get update -qq || true; } &&
      DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq chromium >/dev/null 2>&1; then
    echo "softforce setup: installed chromium (the report's browser test)" >&2
  else
    echo "softforce setup: chromium could not be installed (optional): the report's browser" \
         "test will be skipped" >&2
  fi
fi
exit 0
