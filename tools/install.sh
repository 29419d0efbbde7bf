#!/usr/bin/env bash
# Install ogiflow into ./.venv on Debian (bookworm or later) with Python >= 3.10.
#   tools/install.sh          runtime only
#   tools/install.sh --dev    runtime + test tools + the system packages the tests need
#   tools/install.sh --cluster  runtime + Ray, for `ogiflow reprocess` (extra `cluster`)
# System packages come from apt (with sudo when not root); Python packages from PyPI.
set -euo pipefail
cd "$(dirname "$0")/.."

dev=0
cluster=0
[ "${1:-}" = "--dev" ] && dev=1
[ "${1:-}" = "--cluster" ] && cluster=1

apt_packages=(python3-venv python3-dev)
if [ "$dev" = 1 ]; then
    # Tests (the system packages a test needs are added here).
    # systemd: `systemd-analyze verify` lints the unit file.
    # Cameras: Aravis library + typelib, its fake GigE Vision camera, what PyGObject (the
    # gige extra, built from source) compiles against; iproute2 (ip) for the fake cameras'
    # private network namespace.
    # mosquitto: the MQTT broker the alarm tests publish to (127.0.0.1, a free port).
    # chromium + tesseract-ocr: the browser test of the live view (playwright drives Debian's
    # chromium through executable_path; the viewer draws on a canvas, so OCR reads titles).
    apt_packages+=(systemd gir1.2-aravis-0.8 aravis-tools gcc libgirepository1.0-dev
                   libcairo2-dev pkg-config iproute2 mosquitto chromium tesseract-ocr)
    # Fault injection: stress-ng loads the CPUs beside the daemon (tests/test_faults.py).
    apt_packages+=(stress-ng)
fi

missing=()
for p in "${apt_packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
    sudo=""
    [ "$(id -u)" = 0 ] || sudo="sudo"
    echo "install.sh: installing system packages: ${missing[*]}"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}"
fi

[ -x .venv/bin/python ] || python3 -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
if [ "$dev" = 1 ]; then
    .venv/bin/python -m pip install -q -e ".[dev,gige]"
elif [ "$cluster" = 1 ]; then
    .venv/bin/python -m pip install -q ".[cluster]"
else
    .venv/bin/python -m pip install -q .
fi
echo "install.sh: ogiflow installed in .venv ($(.venv/bin/ogiflow --version))"
if [ "$dev" = 0 ] && [ "$cluster" = 0 ] && [ "${OGIFLOW_NO_WARMUP:-0}" != 1 ]; then
    # What the first `ogiflow run` would otherwise do while acquiring (then it shows a
    # coarse preview and skips pairs): render the simulated scene and compile the solvers.
    echo "install.sh: rendering the simulated scene and compiling the solvers once (~2-3 min;" \
         "OGIFLOW_NO_WARMUP=1 skips it)"
    .venv/bin/ogiflow run --prepare --log-level WARNING
fi
