"""``rsal secure``: a secured fleet's identities and their least-privilege access rules.

A *fleet folder* holds what the fleet's Zenoh router needs to know who is who (Zenoh 1.x
transport authentication and access control, https://zenoh.io/docs/manual/access-control/ and
``DEFAULT_CONFIG.json5`` of eclipse-zenoh): a certificate authority and the router's TLS
certificate (made with ``openssl``), one *identity* per robot host, agent host and operator, each
with its own random password (``transport/auth/usrpwd``: one ``name:password`` line per identity
in the router's dictionary), and the router's access-control rules generated from the identities:

================  =======================================================================
kind              may (everything else is refused: ``default_permission: "deny"``)
================  =======================================================================
``robot``         everything under its own nodes ``rsal/<node>/**`` (tokens, data, events,
                  commands, rpcs served and called); receive any base's emergency stop; run
                  the host daemon ``hosts/<name>`` (``rsal host --name <name>``: its token,
                  requests, its runs' ``out``/``exit``, its launchers' tokens)
``agents``        put ``svc/<service>/<agent>`` and declare ``agents/<agent>`` for its own
                  agents and services; read those services and agents' tokens; answer
                  ``hello`` for its own agents and ask everyone's; drive the robots it is
                  given (``--robots``: commands, rpcs, data) and, with robots, read their
                  true poses from the simulation (its token, ``describe``, ``get_pose``)
``operator``      read every device, service, agent and host daemon; command and call every
                  device (start runs, drive robots, the simulator's ``crowd`` device that moves
                  every robot, emergency stop and release); launch, stop
                  and list agent hosts on host daemons (``hosts/*/rpc/*``) and hold its runs'
                  launcher tokens; no other tokens, no services
``viewer``        read devices' data, events, tokens and ``describe``; press the emergency stop
================  =======================================================================

Every identity may read the simulation's clock (``rsal/*/simulation/*/data``). The folder::

    fleet.json          the identities (kind, nodes, agents, services, robots), host and port
    ca.pem ca.key       the fleet's CA          router.pem router.key   the router's certificate
    credentials.txt     name:password, read by the router only (mode 600)
    router.json5        rsal router --config router.json5
    members/NAME.json5  one identity's client config: --config members/NAME.json5 (mode 600)

Adding or revoking an identity writes that member's file and regenerates ``credentials.txt`` and
``router.json5`` only; the router reads both when it starts (Zenoh cannot reload its access
control), so restart it. Errors are :class:`SecureError`: one line naming the place and a fix.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import secrets
import shutil
import subprocess
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

from .errors import RsalError
from .ownership import owners_query

__all__ = ["SecureError", "Identity", "Fleet", "acl", "register"]

KINDS = ("robot", "agents", "operator", "viewer")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_\-]*$")  # a key chunk and a Zenoh user name; no ':' (dictionary)
ALL_MESSAGES = [
    "put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
    "liveliness_token", "liveliness_query", "declare_liveliness_subscriber",
]  # fmt: skip
CLOCK = "rsal/*/simulation/*/data"
SIMULATION = "rsal/*/simulation/*"  # the simulation device's token
SIM_READS = ("describe", "get_pose")  # what an agent host may ask the simulation (reads only)
# The simulator's crowd device (rsal.interfaces.crowd): its cmd moves every robot of the simulator,
# so only the operator -- who may command every robot's position2d -- may put it; agent hosts,
# given single robots, get no rule that covers it (their rsal/<robot>/** never names the simulator's
# node), and the simulator's own host serves it under its nodes.
CROWD_CMD = "rsal/*/crowd/*/cmd"
HELLO = "hello"  # the agents' discovery service (agents.services), answered per agent
HOSTS = "hosts"  # host daemons (rsal host): hosts/<name>, hosts/<name>/rpc/<op>, hosts/<name>/run/**


class SecureError(RsalError, ValueError):
    """A fleet folder or an identity that cannot be made as asked; one line with the fix."""


def check_name(kind: str, name: str) -> str:
    if not _NAME.match(name or ""):
        raise SecureError(
            f"{kind} {name!r} must start with a letter or digit and hold only letters, digits, '_' or '-'"
            " (it becomes a key chunk and a Zenoh user name)"
        )
    return name


@dataclass
class Identity:
    """One member of the fleet: a robot host, an agent host, an operator or a viewer."""

    name: str
    kind: str
    nodes: list[str] = field(default_factory=list)  # robot: the nodes it serves
    agents: list[str] = field(default_factory=list)  # agents: the agent ids it runs
    services: list[str] = field(default_factory=list)  # agents: the services they speak
    robots: list[str] = field(default_factory=list)  # agents: the robots (nodes) they drive


# -- the access-control rules ------------------------------------------------------------------


def _rule(rid: str, flow: str, messages: list[str], kes: list[str]) -> dict:
    return {"id": rid, "permission": "allow", "flows": [flow], "messages": messages, "key_exprs": kes}


def _read(rid: str, kes: list[str]) -> list[dict]:
    """Subscribe to ``kes`` and receive their samples."""
    return [
        _rule(f"{rid}-sub", "ingress", ["declare_subscriber"], kes),
        _rule(f"{rid}-recv", "egress", ["put", "delete"], kes),
    ]


def _tokens(rid: str, kes: list[str]) -> list[dict]:
    """Look up and follow the liveliness tokens under ``kes``."""
    return [
        _rule(f"{rid}-look", "ingress", ["liveliness_query", "declare_liveliness_subscriber"], kes),
        _rule(f"{rid}-seen", "egress", ["liveliness_token", "reply"], kes),
    ]


def _call(rid: str, kes: list[str]) -> list[dict]:
    """Query ``kes`` (rpcs) and receive the replies."""
    return [_rule(f"{rid}-ask", "ingress", ["query"], kes), _rule(f"{rid}-answer", "egress", ["reply"], kes)]


def _owners(devices: str) -> str:
    """The owner tokens of ``devices`` (rsal.ownership): ``@owner`` is a verbatim chunk, which no
    ``**`` covers, so each rule that grants a device's token names its owner token too."""
    return owners_query(devices)


def _rules_of(ident: Identity) -> list[dict]:
    n = ident.name
    rules = _read(f"{n}-clock", [CLOCK])
    # Declarations the router passes on (someone subscribes, someone serves) tell a member's
    # publishers and queriers where to send; they carry no data, so everyone may receive them.
    rules.append(_rule(f"{n}-decl", "egress", ["declare_subscriber", "declare_queryable"], ["**"]))
    if ident.kind == "robot":
        own = [k for node in ident.nodes for k in (f"rsal/{node}/**", _owners(f"rsal/{node}/*/*"))]
        rules.append(_rule(f"{n}-own-in", "ingress", list(ALL_MESSAGES), own))
        rules.append(_rule(f"{n}-own-out", "egress", list(ALL_MESSAGES), own))
        rules += _host_daemon(ident)
        # ``rsal estop --all`` asks every base at once: the query's key names no robot
        stops = ["rsal/*/position2d/*/rpc/estop", "rsal/*/position2d/*/rpc/release"]
        rules.append(_rule(f"{n}-estop", "egress", ["query"], stops))
    elif ident.kind == "agents":
        # all-to-all (svc/<service>/<agent>) and neighbourhood-scoped (svc/<service>/<cell>/<agent>)
        svc_out = [k for s in ident.services for a in ident.agents for k in (f"svc/{s}/{a}", f"svc/{s}/*/{a}")]
        if svc_out:
            rules.append(_rule(f"{n}-svc-put", "ingress", ["put"], svc_out))
            rules += _read(f"{n}-svc", [f"svc/{s}/**" for s in ident.services])
        rules.append(_rule(f"{n}-token", "ingress", ["liveliness_token"], [f"agents/{a}" for a in ident.agents]))
        rules += _tokens(f"{n}-agents", ["agents/**"])
        # ``hello`` (agent discovery): answer for its own agents only, ask every agent (the
        # question ``svc/hello/*`` names nobody, so it reaches every agent host)
        hello = [f"svc/{HELLO}/{a}" for a in ident.agents]
        rules.append(_rule(f"{n}-hello-serve", "ingress", ["declare_queryable", "reply"], hello))
        rules.append(_rule(f"{n}-hello-asked", "egress", ["query"], [f"svc/{HELLO}/*"]))
        rules += _call(f"{n}-hello", [f"svc/{HELLO}/*"])
        if ident.robots:
            mine = [k for r in ident.robots for k in (f"rsal/{r}/**", _owners(f"rsal/{r}/*/*"))]
            rules += _read(f"{n}-robots", mine) + _tokens(f"{n}-robots", mine)
            rules.append(_rule(f"{n}-drive", "ingress", ["put"], [f"rsal/{r}/*/*/cmd" for r in ident.robots]))
            rules += _call(f"{n}-rpc", [f"rsal/{r}/*/*/rpc/*" for r in ident.robots])
            # a simulated robot's agent anchors its odometry at the robot's true start pose
            rules += _tokens(f"{n}-sim", [SIMULATION, _owners(SIMULATION)])
            rules += _call(f"{n}-sim", [f"{SIMULATION}/rpc/{op}" for op in SIM_READS])
    elif ident.kind == "operator":
        everything = ["rsal/**", _owners("rsal/*/*/*"), "svc/**", "agents/**", "hosts/**"]
        rules += _read(f"{n}-all", everything) + _tokens(f"{n}-all", everything)
        rules.append(_rule(f"{n}-drive", "ingress", ["put"], ["rsal/*/*/*/cmd", CROWD_CMD]))
        rules += _call(f"{n}-rpc", ["rsal/*/*/*/rpc/*"])
        # launch, stop and list agent hosts on the host daemons (rsal run with 'machine:'), and
        # hold the launcher's token of its runs (the daemon stops a run when it goes)
        rules += _call(f"{n}-hosts", [f"{HOSTS}/*/rpc/*"])
        rules.append(_rule(f"{n}-runner", "ingress", ["liveliness_token"], [f"{HOSTS}/*/run/*/runner"]))
    elif ident.kind == "viewer":
        rules += _read(f"{n}-data", ["rsal/*/*/*/data", "rsal/*/*/*/event"])
        rules += _tokens(f"{n}-tokens", ["rsal/**", _owners("rsal/*/*/*"), "agents/**"])
        rules += _call(f"{n}-look", ["rsal/*/*/*/rpc/describe", "rsal/*/position2d/*/rpc/estop"])
    return rules


def _host_daemon(ident: Identity) -> list[dict]:
    """A robot host's ``rsal host`` daemon, named after the identity (``hosts/<name>``): its token,
    the requests it answers, its runs' output and exits, and its launchers' tokens."""
    n, h = ident.name, f"{HOSTS}/{ident.name}"
    rules = [_rule(f"{n}-host-token", "ingress", ["liveliness_token"], [h])]
    rules.append(_rule(f"{n}-host-serve", "ingress", ["declare_queryable", "reply"], [f"{h}/rpc/*"]))
    rules.append(_rule(f"{n}-host-asked", "egress", ["query"], [f"{h}/rpc/*"]))
    rules.append(_rule(f"{n}-host-runs", "ingress", ["put"], [f"{h}/run/*/out", f"{h}/run/*/exit"]))
    return rules + _tokens(f"{n}-host-runners", [f"{h}/run/*/runner"])


def acl(identities: list[Identity]) -> dict:
    """The router's ``access_control`` section: default deny, one subject and its rules per identity."""
    rules, subjects, policies = [], [], []
    for ident in identities:
        mine = _rules_of(ident)
        rules += mine
        subjects.append({"id": ident.name, "usernames": [ident.name]})
        policies.append({"rules": [r["id"] for r in mine], "subjects": [ident.name]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


# -- the fleet folder ----------------------------------------------------------------------------


class Fleet:
    """A fleet folder: :meth:`init` makes it, :meth:`add` and :meth:`revoke` change its identities."""

    def __init__(self, folder: str | Path):
        self.dir = Path(folder).resolve()
        self.meta = self.dir / "fleet.json"

    # reading and writing
    def load(self) -> tuple[dict, list[Identity]]:
        if not self.meta.is_file():
            raise SecureError(f"{self.dir}: no fleet folder here (make one with: rsal secure init --dir {self.dir})")
        try:
            data = json.loads(self.meta.read_text())
            return data, [Identity(**i) for i in data["identities"]]
        except (ValueError, KeyError, TypeError) as e:
            raise SecureError(f"{self.meta}: not a fleet file ({e}); make it again: rsal secure init") from None

    def _save(self, data: dict, idents: list[Identity], passwords: dict[str, str]) -> None:
        data["identities"] = [asdict(i) for i in idents]
        _write(self.meta, json.dumps(data, indent=2) + "\n", 0o600)  # holds the router's own password
        _write(self.dir / "credentials.txt", "".join(f"{i.name}:{passwords[i.name]}\n" for i in idents), 0o600)
        _write(self.dir / "router.json5", self._router_config(data, idents), 0o644)

    def passwords(self) -> dict[str, str]:
        f = self.dir / "credentials.txt"
        if not f.is_file():
            return {}
        return dict(line.split(":", 1) for line in f.read_text().splitlines() if ":" in line)

    def member_config(self, name: str) -> Path:
        return self.dir / "members" / f"{name}.json5"

    # commands
    def init(self, host: str, port: int) -> None:
        if shutil.which("openssl") is None:
            raise SecureError("rsal secure init: openssl is needed to make certificates (apt-get install openssl)")
        if self.meta.exists():
            raise SecureError(f"{self.dir}: a fleet folder is already here (remove it first to start a new fleet)")
        if not 0 < port < 65536:
            raise SecureError(f"--port {port}: a TCP port is 1..65535")
        self.dir.mkdir(parents=True, exist_ok=True)
        (self.dir / "members").mkdir(exist_ok=True, mode=0o700)
        _make_certificates(self.dir, host)
        data = {"host": host, "port": port, "router_password": secrets.token_hex(16)}
        self._save(data, [], {})

    def add(self, ident: Identity) -> Path:
        data, idents = self.load()
        check_name("identity", ident.name)
        if ident.kind not in KINDS:
            raise SecureError(f"identity kind {ident.kind!r}: one of {', '.join(KINDS)}")
        for what in ("nodes", "agents", "services", "robots"):
            for v in getattr(ident, what):
                check_name(what[:-1], v)
        if ident.kind == "robot" and not ident.nodes:
            ident.nodes = [ident.name]
        if ident.kind == "agents" and not (ident.agents and ident.services):
            raise SecureError(f"agent host {ident.name!r}: name its agents and services (--agents A,B --services S,T)")
        if any(i.name == ident.name for i in idents):
            raise SecureError(f"identity {ident.name!r} exists already (rsal secure revoke {ident.name} first)")
        pw = self.passwords()
        pw[ident.name] = secrets.token_hex(16)
        idents.append(ident)
        self._save(data, idents, pw)
        path = self.member_config(ident.name)
        _write(path, self._client_config(data, ident, pw[ident.name]), 0o600)
        return path

    def revoke(self, name: str) -> None:
        data, idents = self.load()
        if not any(i.name == name for i in idents):
            known = ", ".join(i.name for i in idents) or "none"
            raise SecureError(f"no identity {name!r} in {self.dir} (known: {known})")
        pw = self.passwords()
        pw.pop(name, None)
        self._save(data, [i for i in idents if i.name != name], pw)
        self.member_config(name).unlink(missing_ok=True)

    # the configuration files
    def _router_config(self, data: dict, idents: list[Identity]) -> str:
        d = self.dir
        conf = {
            "mode": "router",
            "listen": {"endpoints": [f"tls/{data['host']}:{data['port']}"]},
            "scouting": {"multicast": {"enabled": False}},
            "transport": {
                "link": {
                    "protocols": ["tls"],
                    "tls": {"listen_certificate": str(d / "router.pem"), "listen_private_key": str(d / "router.key")},
                },
                "auth": {
                    "usrpwd": {
                        "user": "router",
                        "password": data["router_password"],
                        "dictionary_file": str(d / "credentials.txt"),
                    }
                },
            },
            "access_control": acl(idents),
        }
        head = "// rsal router --config router.json5 (made by rsal secure; restart the router after a change)\n"
        return head + json.dumps(conf, indent=2) + "\n"

    def _client_config(self, data: dict, ident: Identity, password: str) -> str:
        conf = {
            "mode": "client",
            "connect": {
                "endpoints": [f"tls/{data['host']}:{data['port']}"],
                "timeout_ms": -1,
                "exit_on_failure": False,
            },
            "scouting": {"multicast": {"enabled": False}},
            "transport": {
                "link": {"tls": {"root_ca_certificate": str(self.dir / "ca.pem")}},
                "auth": {"usrpwd": {"user": ident.name, "password": password}},
            },
        }
        return f"// --config {ident.name}.json5 : the {ident.kind} identity {ident.name} (made by rsal secure)\n" + (
            json.dumps(conf, indent=2) + "\n"
        )


def _write(path: Path, text: str, mode: int) -> None:
    tmp = path.with_name(path.name + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.chmod(tmp, mode)
    os.replace(tmp, path)


def _openssl(*args: str) -> None:
    r = subprocess.run(["openssl", *args], capture_output=True, text=True)
    if r.returncode:
        last = (r.stderr.strip().splitlines() or ["no message"])[-1]
        raise SecureError(f"openssl {args[0]} failed: {last}")


def _make_certificates(d: Path, host: str) -> None:
    """The fleet's CA and the router's certificate (CN and subjectAltName = host)."""
    ec = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes")
    _openssl("req", "-x509", *ec, "-days", "825", "-subj", "/CN=RSAL fleet CA",
             "-keyout", str(d / "ca.key"), "-out", str(d / "ca.pem"))  # fmt: skip
    _openssl("req", *ec, "-subj", f"/CN={host}", "-keyout", str(d / "router.key"), "-out", str(d / "router.csr"))
    san = f"IP:{host}" if re.fullmatch(r"[0-9.]+|[0-9a-fA-F:]+", host) else f"DNS:{host}"
    ext = d / "router.ext"
    ext.write_text(f"subjectAltName={san}\nbasicConstraints=CA:FALSE\nextendedKeyUsage=serverAuth\n")
    _openssl("x509", "-req", "-in", str(d / "router.csr"), "-CA", str(d / "ca.pem"), "-CAkey", str(d / "ca.key"),
             "-CAcreateserial", "-days", "825", "-extfile", str(ext), "-out", str(d / "router.pem"))  # fmt: skip
    for f in ("router.csr", "ca.srl", "router.ext"):
        (d / f).unlink(missing_ok=True)
    for f in ("ca.key", "router.key"):
        os.chmod(d / f, 0o600)
    for f in ("ca.pem", "router.pem"):
        os.chmod(d / f, 0o644)


# -- the command line ----------------------------------------------------------------------------


def _names(text: str) -> list[str]:
    return [v.strip() for v in text.split(",") if v.strip()]


def _run(args: argparse.Namespace) -> int:
    fleet = Fleet(args.dir)
    if args.action == "init":
        fleet.init(args.host, args.port)
        print(f"fleet folder {fleet.dir}: router.json5 (tls/{args.host}:{args.port}); now add identities")
        return 0
    if args.action == "revoke":
        fleet.revoke(args.name)
        print(f"revoked {args.name}; restart the router (rsal router --config {fleet.dir / 'router.json5'})")
        return 0
    if args.action == "list":
        _, idents = fleet.load()
        for i in idents:
            extra = {k: v for k, v in asdict(i).items() if k not in ("name", "kind") and v}
            print(f"{i.name}\t{i.kind}\t" + " ".join(f"{k}={','.join(v)}" for k, v in extra.items()))
        return 0
    kind = {"add-robot": "robot", "add-agents": "agents", "add-operator": "operator", "add-viewer": "viewer"}
    ident = Identity(args.name, kind[args.action])
    if args.action == "add-robot":
        ident.nodes = _names(args.nodes or args.name)
    elif args.action == "add-agents":
        ident.agents, ident.services, ident.robots = _names(args.agents), _names(args.services), _names(args.robots)
    path = fleet.add(ident)
    print(f"{ident.kind} {ident.name}: --config {path}; restart the router to admit it")
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "secure",
        help="make a secured fleet: identities per robot, agent host and operator, least-privilege rules",
        description="Make and change a fleet folder for the secured profile (docs/security.md).",
    )
    acts = p.add_subparsers(dest="action", metavar="ACTION", required=True)

    def action(name: str, help: str, named: bool = True):
        a = acts.add_parser(name, help=help, description=help)
        if named:
            a.add_argument("name", metavar="NAME", help="the identity's name (letters, digits, '_', '-')")
        a.add_argument("--dir", required=True, help="the fleet folder")
        return a

    i = action("init", "make the fleet folder: CA, router certificate, router.json5", named=False)
    i.add_argument("--host", default="127.0.0.1", help="where the router listens for TLS (default 127.0.0.1)")
    i.add_argument("--port", type=int, default=7448, help="its TCP port (default 7448)")
    r = action("add-robot", "a robot host: everything under its own nodes rsal/<node>/**")
    r.add_argument("--nodes", help="comma-separated nodes it serves (default: NAME)")
    a = action("add-agents", "an agent host: its agents' tokens and service messages")
    a.add_argument("--agents", required=True, help="comma-separated agent ids it runs")
    a.add_argument("--services", required=True, help="comma-separated services its agents speak")
    a.add_argument("--robots", default="", help="comma-separated robots (nodes) its agents drive")
    action("add-operator", "an operator (rsal run, control center): reads all, drives robots, emergency stop")
    action("add-viewer", "a viewer: data, events, tokens, describe, emergency stop")
    action("revoke", "remove an identity (restart the router)")
    action("list", "print the identities", named=False)
    p.set_defaults(func=_run)


if __name__ == "__main__":  # pragma: no cover
    from .cli import main

    sys.exit(main(["secure", *sys.argv[1:]]))
