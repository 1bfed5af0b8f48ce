#!/usr/bin/env bash
# RSAL fabric developer entry point.
#   ./dev.sh demo [ARGS]   set up .venv if needed, then run the embedded default (rsal demo)
#   ./dev.sh test [ARGS]   set up .venv if needed, then run the whole test suite (pytest)
#   ./dev.sh setup         only set up (or refresh) .venv
# The virtual environment lives in .venv/ at the repository root; it is (re)installed whenever
# pyproject.toml changes. Needs Python 3.11+ and pip; nothing is fetched at run time.
set -euo pipefail
cd "$(dirname "$0")"
PY=${PYTHON:-python3}
VENV=.venv
STAMP=$VENV/.rsal-installed

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
    echo "[setup] done"
  fi
}

cmd=${1:-demo}
[ $# -gt 0 ] && shift
case "$cmd" in
  setup) setup ;;
  demo) setup; exec "$VENV/bin/rsal" demo "$@" ;;
  test) setup; exec "$VENV/bin/python" -m pytest "$@" ;;
  *) echo "dev.sh: unknown command '$cmd' (use: demo, test or setup)" >&2; exit 2 ;;
esac
