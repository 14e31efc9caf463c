#!/usr/bin/env bash
# Install the system Chromium that the web app's browser test drives (Debian's `chromium` package, used by
# Playwright through executable_path: Playwright's own browser downloads are never used).
#
#   scripts/install_browser.sh            install if missing; without root or sudo, say so and carry on
#                                         (tests/web/test_web_e2e.py then skips, naming the reason)
#   scripts/install_browser.sh --require  the same, but fail when no Chromium can be installed (CI)
set -euo pipefail

require=0
[[ "${1:-}" == "--require" ]] && require=1

find_chromium() {
    for candidate in "${FOOTMESH_CHROMIUM:-}" /usr/lib/chromium/chromium "$(command -v chromium || true)" \
                     "$(command -v chromium-browser || true)"; do
        if [[ -n "$candidate" && -x "$candidate" ]]; then
            echo "$candidate"
            return 0
        fi
    done
    return 1
}

if found=$(find_chromium); then
    echo "chromium: $found"
    exit 0
fi

packages=(chromium fonts-dejavu-core)  # SwiftShader (software WebGL) comes inside Debian's chromium package
if [[ $(id -u) -eq 0 ]]; then
    sudo=()
elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then
    sudo=(sudo -n)
else
    echo "chromium is not installed and this user cannot install packages: apt-get install ${packages[*]}" >&2
    echo "(the browser test will be skipped)" >&2
    exit $(( require ? 1 : 0 ))
fi
if ! command -v apt-get >/dev/null; then
    echo "no apt-get here: install Chromium with your system's package manager, or set FOOTMESH_CHROMIUM" >&2
    exit $(( require ? 1 : 0 ))
fi
export DEBIAN_FRONTEND=noninteractive
"${sudo[@]}" apt-get update -qq
"${sudo[@]}" apt-get install -y -qq --no-install-recommends "${packages[@]}" >/dev/null
found=$(find_chromium) || { echo "chromium was installed but not found" >&2; exit 1; }
echo "chromium: $found"
