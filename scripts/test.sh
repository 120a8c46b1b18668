#!/usr/bin/env bash
# All set-up, then the whole test suite (the README's test command; CI runs exactly this).
set -euo pipefail
REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
bash "$REPO/scripts/bootstrap.sh"
cd "$REPO"
# ROS tests must fail, not skip, when the ROS install is broken.
export ELASTIC_PM_DYN_REQUIRE_ROS=1
# The observer's kernels compile on the second core while the first runs the early tests
# (test/warm_kernels.py; on a warm numba cache it only loads them and ends).
nice -n 5 .venv/bin/python test/warm_kernels.py >/dev/null 2>&1 &
exec .venv/bin/python -m pytest "$@"
