#!/usr/bin/env bash
# RSAL fabric developer entry point.
#   ./dev.sh demo [ARGS]   set up .venv if needed, then run the embedded default (rsal demo)
#   ./dev.sh test [ARGS]   set up .venv and the test tools if needed, then run the whole test suite (pytest,
#                          RSAL_TEST_WORKERS test files side by side, 2 unless set; 0: one after another)
#   ./dev.sh setup         only set up (or refresh) .venv and the compiled kernels
# The virtual environment lives in .venv/ at the repository root; it is (re)installed whenever
# pyproject.toml changes. The simulator's and navigation's kernels are compiled into numba's cache
# (rsal warmup) whenever they may be missing, so the first run starts as fast as every later one.
# The test command also installs what the browser test needs from the system (Debian's chromium)
# when it can (root and apt-get). Needs Python 3.11+ and pip; nothing is fetched at run time.
set -euo pipefail
cd "$(dirname "$0")"
PY=${PYTHON:-python3}
VENV=.venv
STAMP=$VENV/.rsal-installed
KSTAMP=$VENV/.rsal-kernels
KERNEL_SOURCES="simulator/raycast.py simulator/warmup.py mrs_bridge/nav/amcl.py mrs_bridge/nav/wavefront.py mrs_bridge/nav/warmup.py"
CHROMIUM=/usr/bin/chromium

setup() {
  if ! "$PY" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' 2>/dev/null; then
    echo "dev.sh: Python 3.11 or newer is needed (found: $("$PY" --version 2>&1)); set PYTHON=/path/to/python3.11" >&2
    exit 1
  fi
  if [ ! -x "$VENV/bin/python" ]; then
    echo "[setup] creating virtual environment in $VENV/"
    "$PY" -m venv "$VENV"
  fi
  want=$(cat pyproject.toml | "$VENV/bin/python" -c 'import hashlib,sys; print(hashlib.sha256(sys.stdin.buffer.read()).hexdigest())')
  if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$want" ]; then
    echo "[setup] installing rsal-fabric and its dependencies into $VENV/ (first run takes a minute)"
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --upgrade pip
    # PYTHONWARNINGS: no setuptools notice boxes about editable installs in the set-up output
    PYTHONWARNINGS=ignore "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -e '.[test]'
    echo "$want" > "$STAMP"
    rm -f "$KSTAMP"
    echo "[setup] done"
  fi
  # numba keys its cache on the kernels' source files (path and modification time) and keeps it in
  # __pycache__ beside them, or under NUMBA_CACHE_DIR: compile again whenever either changed.
  # shellcheck disable=SC2086
  kwant="${NUMBA_CACHE_DIR:-__pycache__} $(stat -c %Y $KERNEL_SOURCES | tr '\n' ' ')"
  if [ ! -f "$KSTAMP" ] || [ "$(cat "$KSTAMP")" != "$kwant" ]; then
    echo "[setup] compiling the simulator's and navigation's kernels (first run only, up to a minute)"
    "$VENV/bin/rsal" warmup
    echo "$kwant" > "$KSTAMP"
  fi
}

test_tools() {
  # The browser test drives Debian's chromium (no browser download); install it once when we can.
  [ -x "$CHROMIUM" ] && return 0
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "[setup] installing Debian's chromium for the browser test (once; a few minutes)"
    export DEBIAN_FRONTEND=noninteractive
    if ! apt-get install -y -qq chromium >/dev/null 2>&1; then
      apt-get update -qq >/dev/null 2>&1 || true
      apt-get install -y -qq chromium >/dev/null 2>&1 || echo "[setup] could not install chromium: the browser test will be skipped"
    fi
    [ -x "$CHROMIUM" ] && echo "[setup] chromium installed: $("$CHROMIUM" --version 2>/dev/null || echo "$CHROMIUM")"
  else
    echo "[setup] $CHROMIUM is missing (install it with: apt-get install chromium): the browser test will be skipped"
  fi
  return 0
}

cmd=${1:-demo}
[ $# -gt 0 ] && shift
case "$cmd" in
  setup) setup ;;
  demo) setup; exec "$VENV/bin/rsal" demo "$@" ;;
  # Test files run side by side (pytest-xdist, each file whole on one worker: its module fixtures
  # stay shared); the suite mostly waits on simulated time and start-ups, and every test takes
  # free ports of its own.
  test) setup; test_tools; exec "$VENV/bin/python" -m pytest -n "${RSAL_TEST_WORKERS:-2}" --dist loadfile "$@" ;;
  *) echo "dev.sh: unknown command '$cmd' (use: demo, test or setup)" >&2; exit 2 ;;
esac
