#!/usr/bin/env bash
# Make this machine ready for the AED toolkit: a project virtual environment and a Vulkan
# device SAPIEN can render with. Idempotent: a second run only checks, in a few seconds.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${AED_VENV:-.venv}
PY=${PYTHON:-python3}
STAMP="$VENV/.aed-installed"

log() { echo "[setup] $*" >&2; }

install_python_env() {
    local want
    want=$(cat pyproject.toml scripts/setup.sh | sha256sum | cut -d' ' -f1)
    if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$want" ]; then
        return
    fi
    log "creating the virtual environment in $VENV"
    [ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
    "$VENV/bin/python" -m pip install -q --upgrade pip
    # torch first, pinned: 2.13.0 is the CPU build on this disk; an open range would pull CUDA (GBs).
    "$VENV/bin/python" -m pip install -q "torch==2.13.0"
    "$VENV/bin/python" -m pip install -q -e ".[dev]"
    echo "$want" > "$STAMP"
}

sapien_finds_device() {
    "$VENV/bin/python" - <<'PY' >/dev/null 2>&1
import sapien
sapien.render.RenderSystem()
PY
}

install_vulkan_driver() {
    # SAPIEN needs VK_KHR_external_semaphore_fd: Mesa lavapipe >= 24.3 (bookworm-backports).
    log "SAPIEN finds no rendering device: installing Mesa lavapipe from bookworm-backports"
    local sources=/etc/apt/sources.list.d/debian.sources mirror
    mirror=$(grep -h -m1 -oE 'https?://[^ ]+/debian/?$' "$sources" /etc/apt/sources.list 2>/dev/null | head -n1 || true)
    mirror=${mirror:-http://deb.debian.org/debian}
    local list=/etc/apt/sources.list.d/aed-backports.list
    [ -f "$list" ] || echo "deb $mirror bookworm-backports main" > "$list"
    local sudo=""
    [ "$(id -u)" = 0 ] || sudo=sudo
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq -t bookworm-backports \
        mesa-vulkan-drivers libvulkan1 >/dev/null
}

install_python_env
if ! sapien_finds_device; then
    install_vulkan_driver
    sapien_finds_device || { log "SAPIEN still finds no rendering device; run: $VENV/bin/aed doctor"; exit 1; }
fi
log "ready ($VENV)"
