#!/usr/bin/env bash
# Build the grasp_fc_msgs interface package (msg_defs/) with plain CMake and install it
# into a venv that holds ROS 2 Jazzy from the PyPI wheels (the venv is the ROS prefix).
#
# Usage: scripts/build_msgs.sh VENV_DIR BUILD_DIR
#   e.g. scripts/build_msgs.sh .venv /tmp/build_msgs
# Afterwards `VENV_DIR/bin/python -c "from grasp_fc_msgs.msg import ContactArray"` works.
set -euo pipefail

if [ "$#" -ne 2 ]; then
    echo "usage: $0 VENV_DIR BUILD_DIR" >&2
    exit 2
fi
venv="$(cd "$1" && pwd)"
build="$2"
src="$(cd "$(dirname "${BASH_SOURCE[0]}")/../msg_defs" && pwd)"
# ament finds the generators' typesupports through the ament index of these prefixes.
export AMENT_PREFIX_PATH="$venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"

cmake -S "$src" -B "$build" \
    -DCMAKE_PREFIX_PATH="$venv" \
    -DCMAKE_INSTALL_PREFIX="$venv" \
    -DPython3_EXECUTABLE="$venv/bin/python" \
    -DBUILD_TESTING=OFF
cmake --build "$build" -j2
cmake --install "$build"
