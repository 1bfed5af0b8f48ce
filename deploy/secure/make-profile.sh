#!/usr/bin/env bash
# Make the secured Zenoh profile of a fleet: a certificate authority, the router's TLS certificate,
# a password per role and the three configuration files that use them.
#
#   deploy/secure/make-profile.sh OUTDIR [HOST] [PORT]
#
# HOST (default 127.0.0.1) and PORT (default 7448) are where `rsal router` listens for TLS. OUTDIR
# gets:
#   ca.pem                     the fleet's CA (every member trusts it)
#   router.pem, router.key     the router's certificate (CN and subjectAltName = HOST) and key
#   credentials.txt            user:password per role (fleet, viewer), read by the router only
#   router.json5               rsal router --config router.json5   (TLS, passwords, access control)
#   fleet.json5                device servers and agents: --config fleet.json5  (may drive robots)
#   viewer.json5               watchers: --config viewer.json5     (may only subscribe)
# Needs openssl. Keys are written with mode 600. Running it again replaces everything in OUTDIR.
set -euo pipefail
if [ $# -lt 1 ]; then
  echo "usage: $0 OUTDIR [HOST] [PORT]" >&2
  exit 2
fi
out=$1
host=${2:-127.0.0.1}
port=${3:-7448}
command -v openssl >/dev/null || { echo "$0: openssl is needed (apt-get install openssl)" >&2; exit 1; }
mkdir -p "$out"
out=$(cd "$out" && pwd)
umask 077

if [[ $host =~ ^[0-9.]+$ ]]; then san="IP:$host"; else san="DNS:$host"; fi
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 825 \
  -subj "/CN=RSAL fleet CA" -keyout "$out/ca.key" -out "$out/ca.pem" 2>/dev/null
openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes \
  -subj "/CN=$host" -keyout "$out/router.key" -out "$out/router.csr" 2>/dev/null
openssl x509 -req -in "$out/router.csr" -CA "$out/ca.pem" -CAkey "$out/ca.key" -CAcreateserial \
  -days 825 -extfile <(printf 'subjectAltName=%s\nbasicConstraints=CA:FALSE\nextendedKeyUsage=serverAuth\n' "$san") \
  -out "$out/router.pem" 2>/dev/null
rm -f "$out/router.csr" "$out/ca.srl"
chmod 644 "$out/ca.pem" "$out/router.pem"

fleet_pw=$(openssl rand -hex 16)
viewer_pw=$(openssl rand -hex 16)
printf 'fleet:%s\nviewer:%s\n' "$fleet_pw" "$viewer_pw" > "$out/credentials.txt"

cat > "$out/router.json5" <<JSON
// rsal router --config router.json5 : the fleet's secured router (made by deploy/secure/make-profile.sh)
{
  mode: "router",
  listen: { endpoints: ["tls/$host:$port"] },
  scouting: { multicast: { enabled: false } },
  transport: {
    link: {
      protocols: ["tls"],
      tls: { listen_certificate: "$out/router.pem", listen_private_key: "$out/router.key" },
    },
    auth: { usrpwd: { user: "router", password: "$(openssl rand -hex 16)", dictionary_file: "$out/credentials.txt" } },
  },
  access_control: {
    enabled: true,
    default_permission: "deny",
    rules: [
      {
        id: "everything",
        permission: "allow",
        flows: ["ingress", "egress"],
        messages: ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
                   "liveliness_token", "liveliness_query", "declare_liveliness_subscriber"],
        key_exprs: ["**"],
      },
      {
        // what a viewer sends: subscriptions and liveliness look-ups, nothing that acts
        id: "watch-in",
        permission: "allow",
        flows: ["ingress"],
        messages: ["declare_subscriber", "liveliness_query", "declare_liveliness_subscriber"],
        key_exprs: ["**"],
      },
      {
        // a viewer that sees a runaway robot may press the emergency stop (one robot's or every
        // base's rpc/estop); releasing it (rpc/release) is the fleet's
        id: "estop-in",
        permission: "allow",
        flows: ["ingress"],
        messages: ["query"],
        key_exprs: ["rsal/*/position2d/*/rpc/estop"],
      },
      {
        // what a viewer receives: data, events, service messages, tokens and liveliness answers
        id: "watch-out",
        permission: "allow",
        flows: ["egress"],
        messages: ["put", "delete", "liveliness_token", "reply"],
        key_exprs: ["**"],
      },
    ],
    subjects: [
      { id: "fleet", usernames: ["fleet"] },
      { id: "viewer", usernames: ["viewer"] },
    ],
    policies: [
      { rules: ["everything"], subjects: ["fleet"] },
      { rules: ["watch-in", "watch-out", "estop-in"], subjects: ["viewer"] },
    ],
  },
}
JSON

for role in fleet viewer; do
  pw=$fleet_pw; [ $role = viewer ] && pw=$viewer_pw
  cat > "$out/$role.json5" <<JSON
// --config $role.json5 : a $role member of the secured fleet (made by deploy/secure/make-profile.sh)
{
  mode: "client",
  connect: { endpoints: ["tls/$host:$port"], timeout_ms: -1, exit_on_failure: false },
  scouting: { multicast: { enabled: false } },
  transport: {
    link: { tls: { root_ca_certificate: "$out/ca.pem" } },
    auth: { usrpwd: { user: "$role", password: "$pw" } },
  },
}
JSON
done
echo "secured profile in $out: router.json5 (tls/$host:$port), fleet.json5, viewer.json5"
