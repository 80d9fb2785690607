#!/usr/bin/env bash
# Check grasp_fc_ros on Python 3.12 (Ubuntu 24.04's Python, Jazzy's reference platform)
# in a throwaway venv: the same pins as 3.11 (constraints.txt: every pinned binary has a
# cp312 wheel), the messages built, the package installed, then a few test files.
#
# Usage: scripts/check_python312.sh [pytest arguments]
#   PYTHON312=/path/to/python3.12 picks the interpreter (default: python3.12 on PATH,
#   then pyenv's). Exits 77 (skip) when there is none; KEEP=1 keeps the temp folder.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
find_python() {
    for candidate in "${PYTHON312:-}" python3.12 \
            "$(pyenv root 2>/dev/null)"/versions/3.12*/bin/python3.12; do
        if [ -n "$candidate" ] && "$candidate" -c \
                'import sys, venv, ensurepip; assert sys.version_info[:2] == (3, 12)' 2>/dev/null; then
            command -v "$candidate"
            return
        fi
    done
    return 1
}
if ! python="$(find_python)"; then
    echo "no Python 3.12 found (set PYTHON312=...): nothing checked" >&2
    exit 77
fi
tmp="$(mktemp -d)"
[ "${KEEP:-0}" = 1 ] || trap 'rm -rf "$tmp"' EXIT
echo "checking with $python ($("$python" --version)) in $tmp"

"$python" -m venv "$tmp/venv"
pip=("$tmp/venv/bin/python" -m pip install --disable-pip-version-check --quiet)
"${pip[@]}" -r "$root/requirements.txt" -r "$root/requirements-test.txt" -c "$root/constraints.txt"
bash "$root/scripts/build_msgs.sh" "$tmp/venv" "$tmp/build" > "$tmp/msgs.log" 2>&1 ||
    { tail -n 30 "$tmp/msgs.log" >&2; exit 1; }
# Not editable: the work tree's own (3.11) editable install stays as it is.
mkdir "$tmp/src"
tar -C "$root" --exclude=./.venv --exclude=./build --exclude=./.git --exclude='*.egg-info' \
    --exclude=./bench_out -cf - . | tar -C "$tmp/src" -xf -
"${pip[@]}" --no-deps --no-build-isolation "$tmp/src"

cd "$tmp/src"
if [ "$#" -eq 0 ]; then
    set -- -x -q test/core/test_input.py test/core/test_torque_sets.py test/markers/test_markers.py \
        test/node/test_params_file.py test/node/test_node_process.py
fi
# The copied tests import the installed package, not the copy: remove the copy's package.
rm -rf grasp_fc_ros
"$tmp/venv/bin/python" -m pytest --timeout=600 -p no:cacheprovider "$@"
