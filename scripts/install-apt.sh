#!/usr/bin/env bash
# Install the Debian packages pano4d needs, only when one is missing (so a second run is instant).
#   mesa-vulkan-drivers + libvulkan1: the Vulkan loader and lavapipe, wgpu's CPU adapter
#   ffmpeg: MP4 previews
#   libimage-exiftool-perl: ExifTool, which tags 360° videos with Google's Spherical Video
#     metadata (`pano4d render --projection equirect`; ffmpeg reads it but does not write it)
#   strace: tests/test_resume.py watches every file a run opens for writing
#   chromium + chromium-driver (same Debian build, so matched versions): tests/test_web.py
#     opens `pano4d serve` and `pano4d web` pages in a real headless browser
set -euo pipefail
packages=(mesa-vulkan-drivers libvulkan1 ffmpeg libimage-exiftool-perl strace chromium
  chromium-driver)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "installing Debian packages: ${missing[*]}"
sudo=""
[ "$(id -u)" -eq 0 ] || sudo="sudo"
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
