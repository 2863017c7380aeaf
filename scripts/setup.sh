#!/usr/bin/env bash
# Make this machine ready for the AED toolkit: a project virtual environment and a Vulkan
# device SAPIEN can render with. Idempotent: a second run only checks, in a few seconds.
# Sourced (`source scripts/setup.sh`), it only defines its functions (the tests call them).
set -euo pipefail

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

# The URI of the first enabled `deb` source serving SUITE, from this machine's apt sources only
# (deb822 `*.sources` and one-line `sources.list`, `*.list` under ROOT, default $AED_APT_ROOT
# or /etc/apt);
# prints nothing when no source serves it.
apt_source_for_suite() {
    local suite=$1 root=${2:-${AED_APT_ROOT:-/etc/apt}} f
    {
        for f in "$root"/sources.list.d/*.sources; do
            [ -f "$f" ] || continue
            awk -v want="$suite" '
                BEGIN { RS = ""; FS = "\n" }
                {
                    types = ""; uris = ""; suites = ""; enabled = "yes"
                    for (i = 1; i <= NF; i++) {
                        if ($i ~ /^[ \t]*#/ || index($i, ":") == 0) continue
                        key = tolower($i); sub(/:.*/, "", key)
                        value = $i; sub(/^[^:]*:[ \t]*/, "", value)
                        if (key == "types") types = value
                        else if (key == "uris") uris = value
                        else if (key == "suites") suites = value
                        else if (key == "enabled") enabled = tolower(value)
                    }
                    if (enabled == "no" || (" " types " ") !~ /[ \t]deb[ \t]/) next
                    n = split(suites, s, /[ \t]+/)
                    for (j = 1; j <= n; j++) if (s[j] == want) { split(uris, u, /[ \t]+/); print u[1] }
                }' "$f"
        done
        for f in "$root"/sources.list "$root"/sources.list.d/*.list; do
            [ -f "$f" ] || continue
            awk -v want="$suite" '
                $1 != "deb" { next }
                {
                    i = 2
                    if ($i ~ /^\[/) { while (i <= NF && $i !~ /\]$/) i++; i++ }  # [arch=... signed-by=...]
                    if ($(i + 1) == want) print $i
                }' "$f"
        done
    } | sed -n 1p  # the first, reading all (head would cut the pipe: pipefail)
}

install_vulkan_driver() {
    # SAPIEN needs VK_KHR_external_semaphore_fd: Mesa lavapipe >= 24.3 (bookworm-backports).
    log "SAPIEN finds no rendering device: installing Mesa lavapipe from bookworm-backports"
    local sudo=""
    [ "$(id -u)" = 0 ] || sudo=sudo
    if [ -z "$(apt_source_for_suite bookworm-backports)" ]; then
        # add the backports suite of the Debian mirror this machine already uses, no other
        local mirror
        mirror=$(apt_source_for_suite bookworm)
        if [ -z "$mirror" ]; then
            log "no apt source serves Debian bookworm here, so there is no mirror to take"
            log "bookworm-backports from. Add the bookworm-backports suite (component main) of the"
            log "Debian mirror you use to your apt sources, then run this script again."
            exit 1
        fi
        log "adding the bookworm-backports suite of $mirror (the mirror already configured)"
        echo "deb $mirror bookworm-backports main" | $sudo tee /etc/apt/sources.list.d/aed-backports.list >/dev/null
    fi
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq -t bookworm-backports \
        mesa-vulkan-drivers libvulkan1 >/dev/null
}

main() {
    cd "$(dirname "${BASH_SOURCE[0]}")/.."
    install_python_env
    if ! sapien_finds_device; then
        install_vulkan_driver
        sapien_finds_device || { log "SAPIEN still finds no rendering device; run: $VENV/bin/aed doctor"; exit 1; }
    fi
    log "ready ($VENV)"
}

if [ "${BASH_SOURCE[0]}" = "$0" ]; then
    main "$@"
fi
