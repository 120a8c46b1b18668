#!/usr/bin/env bash
# All set-up, then the five-bar reference manoeuvre (the README's main command).
# Results (CSV, bag, PNG plots, summary) go to runs/demo/.
set -euo pipefail
REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$REPO/scripts/bootstrap.sh"
cd "$REPO"
exec .venv/bin/python -m elastic_pm_dyn demo --out runs/demo "$@"
