#!/usr/bin/env bash
# Install what the browser (end-to-end) tests of the web UI need, idempotently:
#   * Debian's chromium (+ chromium-driver) with apt-get, when /usr/bin/chromium is missing;
#   * the Python driver `playwright` from PyPI into the project's virtualenv.
#
# Playwright is used ONLY as a driver of the system chromium (executable_path=/usr/bin/chromium):
# this script never runs `playwright install`, which downloads browser builds of its own.
#
# Usage: scripts/install_browser.sh [PYTHON]   (default: .venv/bin/python, else python3)
# Non-interactive; safe to run again (does nothing when everything is present).
set -euo pipefail

cd "$(dirname "$0")/.."

PYTHON="${1:-}"
if [[ -z "$PYTHON" ]]; then
    if [[ -x .venv/bin/python ]]; then PYTHON=.venv/bin/python; else PYTHON=python3; fi
fi
PLAYWRIGHT_SPEC="${PLAYWRIGHT_SPEC:-playwright>=1.40,<2}"

need_apt=()
command -v chromium >/dev/null 2>&1 || [[ -x /usr/bin/chromium ]] || need_apt+=(chromium)
command -v chromedriver >/dev/null 2>&1 || [[ -x /usr/bin/chromedriver ]] || need_apt+=(chromium-driver)
# Fonts, so screenshots show text (chromium pulls some in; this makes it explicit).
[[ -d /usr/share/fonts/truetype/dejavu ]] || need_apt+=(fonts-dejavu-core)

if ((${#need_apt[@]})); then
    echo "install_browser: apt-get install ${need_apt[*]}"
    SUDO=()
    if [[ $(id -u) -ne 0 ]]; then
        if command -v sudo >/dev/null 2>&1; then SUDO=(sudo -n); else
            echo "install_browser: not root and no sudo; install ${need_apt[*]} by hand" >&2
            exit 1
        fi
    fi
    export DEBIAN_FRONTEND=noninteractive
    "${SUDO[@]}" apt-get update -q
    "${SUDO[@]}" apt-get install -y -q --no-install-recommends "${need_apt[@]}"
else
    echo "install_browser: chromium and chromium-driver already installed"
fi

if "$PYTHON" -c "import playwright.sync_api" >/dev/null 2>&1; then
    echo "install_browser: playwright (Python driver) already installed"
else
    echo "install_browser: pip install $PLAYWRIGHT_SPEC"
    "$PYTHON" -m pip install -q "$PLAYWRIGHT_SPEC"
fi

chromium --version 2>/dev/null || /usr/bin/chromium --version
