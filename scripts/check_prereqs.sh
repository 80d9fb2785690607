#!/usr/bin/env bash
# Check what the setup needs from the machine before it downloads anything, and say
# what to do about anything missing.
#
# Usage: scripts/check_prereqs.sh PYTHON
#   PYTHON: the interpreter the venv will be made with (default python3.11); Python
#   3.11 or 3.12 (the ROS 2 Jazzy wheels and every pin in constraints.txt exist for both;
#   3.12 is checked by scripts/check_python312.sh).
# Exits 1 after listing every missing prerequisite.
set -uo pipefail

python="${1:-python3.11}"
required_python="3.11"            # the default, what the docs name
supported_pythons=("3.11" "3.12")
supported_text="3.11 or 3.12"
# rosidl's CMake code of ROS 2 Jazzy asks for this version.
required_cmake="3.20"
problems=()

version_at_least() {  # version_at_least HAVE NEED: true when HAVE >= NEED
    [ "$(printf '%s\n%s\n' "$2" "$1" | sort -V | head -n1)" = "$2" ]
}

if [ "$(uname -s)" != "Linux" ]; then
    problems+=("ROS 2 Jazzy's PyPI wheels are built for Linux only; this is $(uname -s).")
elif [ "$(uname -m)" != "x86_64" ]; then
    echo "warning: ROS 2 Jazzy's PyPI wheels were tried on x86_64 only; this is $(uname -m)." >&2
fi

if ! command -v "$python" >/dev/null 2>&1; then
    problems+=("No '$python' on PATH. Install Python $required_python (Debian/Ubuntu:" \
        "  apt-get install python$required_python python$required_python-venv; or pyenv install $required_python)," \
        "  or pass its path: make PYTHON=/path/to/python$required_python ...")
else
    have_python="$("$python" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null)"
    if [ -z "$have_python" ]; then
        problems+=("'$python' is on PATH but does not run. Install Python $required_python or pass" \
            "  its path: make PYTHON=/path/to/python$required_python ...")
    elif [[ ! " ${supported_pythons[*]} " =~ " $have_python " ]]; then
        problems+=("'$python' is Python $have_python; the pinned ROS 2 Jazzy wheels and" \
            "  dependencies need Python $supported_text. Pass one: make PYTHON=/path/to/python$required_python ...")
    elif ! "$python" -c 'import venv, ensurepip' >/dev/null 2>&1; then
        problems+=("'$python' cannot create virtual environments (no venv/ensurepip module)." \
            "  Debian/Ubuntu: apt-get install python$have_python-venv")
    fi
fi

if ! command -v cmake >/dev/null 2>&1; then
    problems+=("No 'cmake' on PATH; building the message package needs CMake >= $required_cmake." \
        "  Debian/Ubuntu: apt-get install cmake   (or: pip install --user cmake)")
else
    have_cmake="$(cmake --version | head -n1 | awk '{print $3}')"
    if ! version_at_least "$have_cmake" "$required_cmake"; then
        problems+=("cmake is $have_cmake; building the message package needs CMake >= $required_cmake." \
            "  Install a newer one (e.g. pip install --user cmake) and put it first on PATH.")
    fi
fi

# Compile and link a trivial program with the compilers CMake would pick.
scratch="$(mktemp -d)"
trap 'rm -rf "$scratch"' EXIT
echo 'int main(void) { return 0; }' >"$scratch/probe.c"
if ! "${CC:-cc}" "$scratch/probe.c" -o "$scratch/probe_c" >/dev/null 2>&1; then
    problems+=("No working C compiler ('${CC:-cc}'); the message package has C code to compile." \
        "  Debian/Ubuntu: apt-get install build-essential")
fi
cp "$scratch/probe.c" "$scratch/probe.cpp"
if ! "${CXX:-c++}" "$scratch/probe.cpp" -o "$scratch/probe_cxx" >/dev/null 2>&1; then
    problems+=("No working C++ compiler ('${CXX:-c++}'); the message package has C++ code to compile." \
        "  Debian/Ubuntu: apt-get install build-essential")
fi

if [ "${#problems[@]}" -gt 0 ]; then
    echo "Missing prerequisites:" >&2
    printf '  %s\n' "${problems[@]}" >&2
    exit 1
fi
echo "prerequisites ok: Python $have_python ($python), CMake $have_cmake, C and C++ compilers"
