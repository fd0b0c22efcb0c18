#!/usr/bin/env bash
# Create .venv and install FuseFlow into it: `bash scripts/setup.sh` (runtime) or
# `bash scripts/setup.sh test` (with the test extras). Installs the one Debian package Open3D
# needs to import (libusb-1.0-0) when it is missing and we may install packages.
set -euo pipefail
cd "$(dirname "$0")/.."
extras="${1:-}"
# Another apt-get or dpkg (unattended-upgrades on a fresh machine) holding the package lock:
# wait for it, up to APT_LOCK_WAIT seconds, instead of failing at once with exit 100.
APT_LOCK_WAIT="${APT_LOCK_WAIT:-600}"
apt_get() {
    echo "  (apt-get waits up to ${APT_LOCK_WAIT} s for the package lock if another package manager holds it)" >&2
    $SUDO apt-get -o DPkg::Lock::Timeout="$APT_LOCK_WAIT" "$@"
}
if ! ldconfig -p 2>/dev/null | grep 'libusb-1.0.so.0' >/dev/null; then  # not grep -q: under pipefail its early exit SIGPIPEs ldconfig
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    echo "installing libusb-1.0-0 (needed by open3d)" >&2
    apt_get update -qq >/dev/null && apt_get install -y -qq libusb-1.0-0 >/dev/null
fi
# The test extra's browser test of the live viewer (tests/live/test_browser.py) drives Debian's
# headless Chromium through its chromedriver: install both when missing.
if [ "$extras" = "test" ] && ! { command -v chromium >/dev/null && command -v chromedriver >/dev/null; }; then
    if [ "$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi
    echo "installing chromium and chromium-driver (the live viewer's browser test)" >&2
    apt_get update -qq >/dev/null && apt_get install -y -qq chromium chromium-driver >/dev/null
fi
# The test extra installs about 4 GB into .venv (open3d 0.9 GB, torch 0.75 GB, rerun 0.5 GB, ray
# 0.25 GB). pip's wheel cache would hold a second copy of what it downloads, so it is off: one CI
# run failed with "No space left on device" during this install. Free space is printed for that.
echo "free disk space where .venv goes: $(df -h . | awk 'NR==2 {print $4}')" >&2
export PIP_NO_CACHE_DIR=1
python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
if [ -n "$extras" ]; then
    .venv/bin/python -m pip install -q -e ".[$extras]"
else
    .venv/bin/python -m pip install -q -e .
fi
# Compile the numba kernels now (cached on disk beside the installed package), so that a
# newcomer's first simulated or fused frame does not wait ~20 s for the compiler.
warm=$(mktemp -d)
if .venv/bin/fuseflow simulate "$warm/rec" --cameras 2 --num-frames 1 --resolution 64x48 >/dev/null \
    && .venv/bin/fuseflow fuse "$warm/rec" --out "$warm/out" >/dev/null; then
    echo "compiled the FUSE and simulator kernels" >&2
else
    echo "warning: kernel warm-up failed; the first frame will compile them" >&2
fi
# With the live server installed (the live and test extras), the viewer's point-cloud codec too
# (about 20 s of compiling that the first `fuseflow live --serve` frame would otherwise wait for).
if .venv/bin/python -c "import websockets" 2>/dev/null; then
    if .venv/bin/fuseflow live "$warm/rec" --serve 127.0.0.1:0 --num-frames 1 >/dev/null 2>&1; then
        echo "compiled the live viewer's codec kernels" >&2
    else
        echo "warning: live codec warm-up failed; the first served frame will compile them" >&2
    fi
fi
rm -rf "$warm"
