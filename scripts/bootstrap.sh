#!/usr/bin/env bash
# Create (or reuse) the project venv and install the package with its Python deps,
# then pip-only ROS 2 Jazzy and our messages (scripts/setup_ros.sh).
#
# Usage: bash scripts/bootstrap.sh [VENV_DIR]     (default: .venv in the repository)
# Needs only python3 (3.11+) and bash; as root on Debian/Ubuntu it apt-installs what a
# fresh machine lacks (python3-venv, cmake, g++).
set -euo pipefail
REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV=${1:-$REPO/.venv}
log() { echo "bootstrap: $*"; }
die() { echo "bootstrap: ERROR: $*" >&2; exit 1; }

command -v python3 >/dev/null || die "python3 not found (install Python 3.11+)"
python3 -c 'import sys; sys.exit(sys.version_info < (3, 11))' ||
    die "Python 3.11+ needed, found $(python3 --version 2>&1)"

if [ ! -x "$VENV/bin/python" ]; then
    if ! python3 -m venv "$VENV" 2>/dev/null; then
        rm -rf "$VENV"
        if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
            log "installing python3-venv with apt-get"
            export DEBIAN_FRONTEND=noninteractive
            apt-get update -q && apt-get install -y -q python3-venv
            python3 -m venv "$VENV"
        else
            die "python3 -m venv failed: install python3-venv (Debian/Ubuntu) and retry"
        fi
    fi
fi
PY=$VENV/bin/python

# Reinstall only when the declared dependencies change.
STAMP=$VENV/.elastic_pm_dyn_deps
HASH=$(cat "$REPO/setup.py" | sha256sum | cut -d' ' -f1)
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$HASH" ]; then
    log "installing elastic_pm_dyn and its Python dependencies into $VENV"
    "$PY" -m pip install -q --upgrade pip 2>&1 | grep -v 'is ignored' || true
    "$PY" -m pip install -q -e "$REPO[test]" 2>&1 | grep -v 'is ignored' || true
    "$PY" -c 'import elastic_pm_dyn, numba, scipy, yaml, matplotlib, pytest' ||
        die "pip install of elastic_pm_dyn failed"
    echo "$HASH" >"$STAMP"
fi
bash "$REPO/scripts/setup_ros.sh" "$VENV"
