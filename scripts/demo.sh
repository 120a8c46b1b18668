#!/usr/bin/env bash
# All set-up, then the five-bar reference manoeuvre through ROS 2 (the README's main command):
# plant, feedforward and recorder nodes as processes -> runs/demo/ (bag, PNG plots, summary, logs).
# The offline comparison of the formulations: .venv/bin/elastic-pm-dyn demo --out runs/offline
set -euo pipefail
REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$REPO/scripts/bootstrap.sh"
cd "$REPO"
exec .venv/bin/python -m elastic_pm_dyn ros-demo --out runs/demo "$@"
