#!/usr/bin/env bash
# Make a secured fleet folder with an operator and a viewer: a thin wrapper of `rsal secure`
# (docs/security.md), kept for the command line the deployment docs used to give.
#
#   deploy/secure/make-profile.sh OUTDIR [HOST] [PORT]
#
# HOST (default 127.0.0.1) and PORT (default 7448) are where `rsal router` listens for TLS. OUTDIR
# gets the fleet folder (ca.pem, router.pem/.key, credentials.txt, router.json5, fleet.json) and
#   members/fleet.json5    an operator: rsal run, control, drive robots, emergency stop and release
#   members/viewer.json5   a viewer: data, events, tokens, describe, emergency stop
# Robot hosts and agent hosts each get their own identity, e.g.
#   rsal secure add-robot r1 --dir OUTDIR
#   rsal secure add-agents hostA --agents hunter-1 --services send_position,outcome --robots r1 --dir OUTDIR
# then restart the router. Needs openssl. OUTDIR must not hold a fleet folder yet.
set -euo pipefail
if [ $# -lt 1 ]; then
  echo "usage: $0 OUTDIR [HOST] [PORT]" >&2
  exit 2
fi
root=$(cd "$(dirname "$0")/../.." && pwd)
rsal=$root/.venv/bin/rsal
[ -x "$rsal" ] || rsal=$(command -v rsal) || { echo "$0: rsal not found (run ./dev.sh setup in $root)" >&2; exit 1; }
"$rsal" secure init --dir "$1" --host "${2:-127.0.0.1}" --port "${3:-7448}"
"$rsal" secure add-operator fleet --dir "$1"
"$rsal" secure add-viewer viewer --dir "$1"
