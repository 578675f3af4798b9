#!/usr/bin/env bash
# System libraries that softforce's wheels load at run time, installed only if missing:
#   libusb-1.0-0   open3d and pyrealsense2 (USB access to RealSense cameras)
#   libgl1 libgomp1 libx11-6           open3d's rendering and OpenMP
#   libglu1-mesa libxrender1 libxcursor1 libxft2 libxinerama1   gmsh's shared library
set -euo pipefail
packages=(libusb-1.0-0 libgl1 libgomp1 libx11-6 libglu1-mesa libxrender1 libxcursor1 libxft2
          libxinerama1)
missing=()
for package in "${packages[@]}"; do
  dpkg -s "$package" >/dev/null 2>&1 || missing+=("$package")
done
[ ${#missing[@]} -eq 0 ] && exit 0
if ! command -v apt-get >/dev/null 2>&1; then
  echo "softforce setup: missing system libraries ${missing[*]} and no apt-get; install them" \
       "with your package manager" >&2
  exit 1
fi
sudo=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null 2>&1 || {
    echo "softforce setup: run as root or install sudo to get ${missing[*]}" >&2; exit 1; }
  sudo="sudo"
fi
echo "softforce setup: installing ${missing[*]}" >&2
$sudo apt-get update -qq || true
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}" >/dev/null
