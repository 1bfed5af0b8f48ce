"""Identities and least privilege by key space (``rsal secure``, docs/security.md).

A fleet folder made in a temporary folder: robot hosts ``r1`` and ``r2``, agent host ``hostA``
(agent ``hunter-1``, driving ``r1``), an operator and a viewer; ``rsal router`` runs with the
generated rules and is killed by PID. Every refusal has its positive twin sent through the same
router at the same time: the forged message never arrives while the genuine one does, so the wait
for the genuine one is the deadline for the forged one (no fixed sleep).

- robot host r1 cannot drive r2, cannot declare r2's tokens, cannot publish r2's laser, cannot
  answer r2's rpc; it serves and drives its own;
- agent host A publishes and announces only its own agent: no outcome for an agent it does not run
  (nor from a robot host), no answer to the rpc of a robot it drives;
- the viewer reads data and tokens but cannot put a command;
- a revoked identity cannot connect; a current one can.

Plus the folder itself: adding a robot leaves the other members' files untouched, errors are one
line. Skipped with the reason when openssl is missing.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import threading
import time

import pytest
import zenoh

from rsal.client import query_rpc
from rsal.keys import parse_device
from rsal.msgs import decode_map, ok_reply
from rsal.ownership import DeviceToken
from rsal.secure import Fleet, Identity, SecureError
from rsal.transport import TransportArgs, open_session
from tests.conftest import Proc, free_port, rsal_cmd, wait_until

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed to make certificates")

MEMBERS = ("r1", "r2", "hostA", "hostB", "op", "view")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """The fleet folder, the router and one open session per member; yields (Fleet, sessions, revoked config)."""
    f = Fleet(tmp_path_factory.mktemp("fleet") / "fleet")
    f.init("127.0.0.1", free_port())
    f.add(Identity("r1", "robot"))
    f.add(Identity("r2", "robot"))
    f.add(Identity("hostA", "agents", agents=["hunter-1"], services=["send_position", "outcome"], robots=["r1"]))
    f.add(Identity("hostB", "agents", agents=["prey-1"], services=["send_position"]))
    f.add(Identity("op", "operator"))
    f.add(Identity("view", "viewer"))
    gone = f.add(Identity("gone", "robot")).read_text()
    f.revoke("gone")
    router = Proc(rsal_cmd("router", "--config", str(f.dir / "router.json5")))
    sessions = {}
    try:
        wait_until(lambda: "routing on" in router.output(), 30, "the router to listen")
        for name in MEMBERS:
            sessions[name] = open_session(TransportArgs(config=str(f.member_config(name))))
        yield f, sessions, gone
    finally:
        for s in sessions.values():
            s.close()
        router.close()


class Inbox:
    """The payloads a subscriber receives."""

    def __init__(self, session, keyexpr: str):
        self.lock = threading.Lock()
        self.got: list[tuple[str, bytes]] = []
        self.sub = session.declare_subscriber(keyexpr, self._on)

    def _on(self, sample) -> None:
        with self.lock:
            self.got.append((str(sample.key_expr), sample.payload.to_bytes()))

    def count(self, payload: bytes) -> int:
        with self.lock:
            return sum(1 for _, p in self.got if p == payload)


def forged_never_arrives(inbox: Inbox, forger, key: str, genuine, gkey: str, what: str) -> None:
    """Put a forged and a genuine message in turns until 5 genuine ones arrived; no forged one may."""

    def five_genuine() -> bool:
        forger.put(key, b"forged")
        genuine.put(gkey, b"genuine")
        return inbox.count(b"genuine") >= 5

    wait_until(five_genuine, 30, f"the genuine messages ({what})", interval=0.05)
    assert inbox.count(b"forged") == 0, f"{what}: a forged message arrived"


def _tokens(session, keyexpr: str) -> list[str]:
    return sorted(str(r.ok.key_expr) for r in session.liveliness().get(keyexpr, timeout=5.0) if r.ok)


def test_a_robot_host_cannot_drive_another_robot_but_the_operator_and_its_agents_can(fleet):
    _, s, _ = fleet
    r2_cmd = Inbox(s["r2"], "rsal/r2/position2d/0/cmd")
    forged_never_arrives(r2_cmd, s["r1"], "rsal/r2/position2d/0/cmd", s["op"], "rsal/r2/position2d/0/cmd", "r1->r2")
    r1_cmd = Inbox(s["r1"], "rsal/r1/position2d/0/cmd")
    # the agent host drives the robot it was given (r1), not r2
    forged_never_arrives(r2_cmd, s["hostA"], "rsal/r2/position2d/0/cmd", s["op"], "rsal/r2/position2d/0/cmd", "A->r2")
    forged_never_arrives(r1_cmd, s["r2"], "rsal/r1/position2d/0/cmd", s["hostA"], "rsal/r1/position2d/0/cmd", "A->r1")


def test_a_robot_host_cannot_publish_another_robots_laser(fleet):
    _, s, _ = fleet
    seen = Inbox(s["view"], "rsal/*/laser/0/data")
    forged_never_arrives(seen, s["r1"], "rsal/r2/laser/0/data", s["r2"], "rsal/r2/laser/0/data", "r1 as r2's laser")
    n = seen.count(b"genuine")
    wait_until(
        lambda: (s["r1"].put("rsal/r1/laser/0/data", b"genuine"), seen.count(b"genuine") > n)[1], 10, "r1's own laser"
    )


def test_a_robot_host_announces_and_answers_only_its_own_devices(fleet):
    _, s, _ = fleet
    forged = s["r1"].liveliness().declare_token("rsal/r2/laser/0")  # declared first: it would be seen first
    own = s["r1"].liveliness().declare_token("rsal/r1/laser/0")
    rogue = s["r1"].declare_queryable("rsal/r2/position2d/0/rpc/describe", lambda q: q.reply(q.key_expr, b"rogue"))
    real = s["r2"].declare_queryable("rsal/r2/position2d/0/rpc/describe", lambda q: q.reply(q.key_expr, b"r2"))
    try:
        seen = wait_until(lambda: _tokens(s["op"], "rsal/**") or None, 20, "r1's own token at the operator")
        assert seen == ["rsal/r1/laser/0"], f"tokens seen by the operator: {seen}"
        assert _tokens(s["view"], "rsal/**") == ["rsal/r1/laser/0"]
        for _ in range(5):
            answers = [
                r.ok.payload.to_bytes() for r in s["op"].get("rsal/r2/position2d/0/rpc/describe", timeout=3) if r.ok
            ]
            assert answers == [b"r2"], f"r2's describe answered by {answers}"
    finally:
        for x in (forged, own, rogue, real):
            x.undeclare()


def test_an_agent_host_speaks_and_lives_only_as_its_own_agents(fleet):
    _, s, _ = fleet
    inbox = Inbox(s["op"], "svc/send_position/*")
    genuine_key, forged_key = "svc/send_position/hunter-1", "svc/send_position/hunter-2"
    forged_never_arrives(inbox, s["hostA"], forged_key, s["hostA"], genuine_key, "A as hunter-2")
    assert {k for k, p in inbox.got if p == b"genuine"} == {genuine_key}
    forged = s["hostA"].liveliness().declare_token("agents/hunter-2")
    own = s["hostA"].liveliness().declare_token("agents/hunter-1")
    try:
        seen = wait_until(lambda: _tokens(s["op"], "agents/**") or None, 20, "hunter-1's token at the operator")
        assert seen == ["agents/hunter-1"]
    finally:
        forged.undeclare()
        own.undeclare()


def test_a_fleet_member_cannot_forge_an_outcome_for_an_agent_it_does_not_run(fleet):
    _, s, _ = fleet
    # the agent host speaks the outcome service for its own agent only
    inbox = Inbox(s["op"], "svc/outcome/*")
    forged_never_arrives(inbox, s["hostA"], "svc/outcome/hunter-2", s["hostA"], "svc/outcome/hunter-1", "A as hunter-2")
    assert {k for k, p in inbox.got} == {"svc/outcome/hunter-1"}
    # a robot host speaks for no agent at all, not even the one that drives it
    inbox = Inbox(s["op"], "svc/outcome/*")
    forged_never_arrives(inbox, s["r1"], "svc/outcome/hunter-1", s["hostA"], "svc/outcome/hunter-1", "r1 as hunter-1")


def test_a_fleet_member_cannot_answer_another_robots_rpc(fleet):
    """Robot host r2 and agent host A (which may call r1's rpcs) both serve r1's ``describe``: only
    r1's answers reach the operator, through Zenoh and through the project's rpc client. Agent host
    A's own rogue answer reaches A itself (a session's local queryables pass no router), and A's
    rpc client drops it: A's session does not own r1's device."""
    _, s, _ = fleet
    key = "rsal/r1/position2d/0/rpc/describe"
    real = s["r1"].declare_queryable(key, lambda q: q.reply(q.key_expr, ok_reply(who="r1")))
    token = DeviceToken(s["r1"], "rsal/r1/position2d/0")  # with its owner token, as r1's server declares it
    rogues = [s[n].declare_queryable(key, lambda q, n=n: q.reply(q.key_expr, ok_reply(who=n))) for n in ("r2", "hostA")]
    try:
        wait_until(lambda: _tokens(s["op"], "rsal/r1/**") == ["rsal/r1/position2d/0"], 20, "r1's token at the operator")
        for _ in range(5):
            answers = [decode_map(r.ok.payload.to_bytes())["who"] for r in s["op"].get(key, timeout=3) if r.ok]
            assert answers == ["r1"], f"r1's describe answered by {answers}"
        # the agent host's own rpc client (the one agents use) gets r1's answer too
        for asker in ("op", "hostA"):
            got: list = []
            query_rpc(s[asker], parse_device("r1:position2d:0"), "describe", None, 3.0, got.append)
            wait_until(lambda got=got: got, 10, f"{asker}'s describe of r1")
            assert isinstance(got[0], dict) and got[0]["who"] == "r1", f"{asker} got {got[0]!r}"
    finally:
        for x in (real, token, *rogues):
            x.undeclare()


def test_an_agent_host_answers_hello_only_for_its_own_agents(fleet):
    _, s, _ = fleet
    serve = [
        s["hostA"].declare_queryable(f"svc/hello/{a}", lambda q, a=a: q.reply(f"svc/hello/{a}", a.encode()))
        for a in ("hunter-2", "hunter-1")  # hunter-2 (not hostA's) declared first
    ]
    try:

        def answers() -> list[bytes]:
            return sorted(r.ok.payload.to_bytes() for r in s["hostB"].get("svc/hello/*", timeout=3) if r.ok)

        assert wait_until(lambda: answers() or None, 20, "hunter-1's hello at agent host B") == [b"hunter-1"]
        assert answers() == [b"hunter-1"]
    finally:
        for q in serve:
            q.undeclare()


def test_the_viewer_reads_but_cannot_command(fleet):
    _, s, _ = fleet
    r1_cmd = Inbox(s["r1"], "rsal/r1/position2d/0/cmd")
    forged_never_arrives(r1_cmd, s["view"], "rsal/r1/position2d/0/cmd", s["op"], "rsal/r1/position2d/0/cmd", "viewer")
    # nor does it read commands or services: the operator's command above reached r1, not the viewer
    watch = Inbox(s["view"], "rsal/r1/position2d/0/cmd")
    data = Inbox(s["view"], "rsal/r1/position2d/0/data")

    def both_sent() -> bool:
        s["op"].put("rsal/r1/position2d/0/cmd", b"genuine")
        s["r1"].put("rsal/r1/position2d/0/data", b"genuine")
        return data.count(b"genuine") >= 5 and r1_cmd.count(b"genuine") >= 10

    wait_until(both_sent, 30, "r1's data at the viewer", interval=0.05)
    assert watch.got == [], "the viewer received a velocity command"


def _strict(path_text: str, tmp_path) -> zenoh.Config:
    """A member's config that gives up at once instead of retrying forever."""
    p = tmp_path / "member.json5"
    p.write_text(path_text)
    c = zenoh.Config.from_file(str(p))
    c.insert_json5("connect/timeout_ms", "3000")
    c.insert_json5("connect/exit_on_failure", "true")
    return c


def test_a_revoked_identity_cannot_connect_and_a_current_one_can(fleet, tmp_path):
    f, _, gone = fleet
    with pytest.raises(zenoh.ZError):
        zenoh.open(_strict(gone, tmp_path)).close()
        pytest.fail("a revoked identity could connect")
    zenoh.open(_strict(f.member_config("r2").read_text(), tmp_path)).close()


def test_adding_a_robot_touches_no_other_member(tmp_path):
    f = Fleet(tmp_path / "fleet")
    f.init("127.0.0.1", 7448)
    f.add(Identity("r1", "robot"))
    f.add(Identity("op", "operator"))
    before = {n: f.member_config(n).read_bytes() for n in ("r1", "op")}
    pw = f.passwords()
    rules = (f.dir / "router.json5").read_text()
    f.add(Identity("r3", "robot", nodes=["r3", "sim"]))
    assert {n: f.member_config(n).read_bytes() for n in ("r1", "op")} == before
    assert {k: v for k, v in f.passwords().items() if k != "r3"} == pw and "r3" in f.passwords()
    after = (f.dir / "router.json5").read_text()
    assert after != rules and "rsal/r3/**" in after and "rsal/sim/**" in after
    assert oct(f.member_config("r3").stat().st_mode & 0o777) == "0o600"
    f.revoke("r3")
    assert "r3" not in f.passwords() and not f.member_config("r3").exists()
    assert (f.dir / "router.json5").read_text() == rules


USER_ERRORS = [
    (["add-robot", "r/1"], "rsal secure: identity 'r/1' must start with a letter or digit"),
    (["add-robot", "r1", "--nodes", "r1,*"], "rsal secure: node '*' must start with a letter or digit"),
    (["add-agents", "hostA", "--agents", "", "--services", "s"], "rsal secure: agent host 'hostA': name its"),
    (["revoke", "nobody"], "rsal secure: no identity 'nobody'"),
    (["add-robot", "r1", "--dir", "missing"], "no fleet folder here (make one with: rsal secure init --dir"),
]


@pytest.fixture(scope="module")
def user_errors(tmp_path_factory) -> dict[tuple, subprocess.CompletedProcess]:
    """Each of ``USER_ERRORS``' command lines run by ``rsal secure`` in a folder of its own with a
    fresh fleet, all at once (independent refusals, started together); stopped by PID if still
    running. Keyed by the command line (``tuple(argv)``)."""
    started: dict[tuple, subprocess.Popen] = {}
    try:
        for argv, _ in USER_ERRORS:
            d = tmp_path_factory.mktemp("secure")
            Fleet(d / "fleet").init("127.0.0.1", 7448)
            folder = [] if "--dir" in argv else ["--dir", str(d / "fleet")]
            started[tuple(argv)] = subprocess.Popen(
                [sys.executable, "-m", "rsal.cli", "secure", *argv, *folder],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                cwd=d,
                start_new_session=True,
            )
        deadline = time.monotonic() + 120
        done = {}
        for key, p in started.items():
            out, err = p.communicate(timeout=max(1.0, deadline - time.monotonic()))
            done[key] = subprocess.CompletedProcess(p.args, p.returncode, out, err)
        return done
    finally:
        for p in started.values():
            if p.poll() is None:
                p.kill()
                p.wait(5)


@pytest.mark.parametrize("argv, says", USER_ERRORS)
def test_user_errors_are_one_line(user_errors, argv, says):
    r = user_errors[tuple(argv)]
    assert r.args[4 : 4 + len(argv)] == argv
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert says in r.stderr, r.stderr


def test_name_errors_name_the_value(tmp_path):
    f = Fleet(tmp_path / "fleet")
    f.init("127.0.0.1", 7448)
    with pytest.raises(SecureError, match="identity 'r/1'"):
        f.add(Identity("r/1", "robot"))
    with pytest.raises(SecureError, match="node '\\*'"):
        f.add(Identity("r1", "robot", nodes=["r1", "*"]))
    with pytest.raises(SecureError, match="name its agents and services"):
        f.add(Identity("hostA", "agents", agents=["a"]))
    f.add(Identity("r1", "robot"))
    with pytest.raises(SecureError, match="exists already"):
        f.add(Identity("r1", "robot"))
    with pytest.raises(SecureError, match="no identity 'r9'.*known: r1"):
        f.revoke("r9")
    with pytest.raises(SecureError, match="already here"):
        f.init("127.0.0.1", 7448)


def test_without_openssl_init_says_so(tmp_path, monkeypatch):
    monkeypatch.setattr("rsal.secure.shutil.which", lambda name: None)
    with pytest.raises(SecureError, match="openssl is needed"):
        Fleet(tmp_path / "fleet").init("127.0.0.1", 7448)
    assert not (tmp_path / "fleet").exists()


def test_the_command_line_makes_and_lists_identities(tmp_path):
    import subprocess
    import sys

    def rsal(*argv: str) -> str:
        r = subprocess.run(
            [sys.executable, "-m", "rsal.cli", "secure", *argv, "--dir", str(tmp_path / "f")],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert r.returncode == 0, r.stderr
        return r.stdout

    rsal("init", "--port", "7448")
    assert "members/r1.json5" in rsal("add-robot", "r1")
    rsal(
        "add-agents", "hostA", "--agents", "hunter-1,hunter-2", "--services", "send_position,outcome", "--robots", "r1"
    )
    rsal("add-viewer", "wall")
    assert "restart the router" in rsal("revoke", "wall")
    assert rsal("list").splitlines() == [
        "r1\trobot\tnodes=r1",
        "hostA\tagents\tagents=hunter-1,hunter-2 services=send_position,outcome robots=r1",
    ]


def test_only_the_operator_launches_on_a_host_daemon(fleet):
    """Robot host r1 runs the host daemon ``hosts/r1`` (rsal host): the operator's requests reach it
    and its launcher token is seen there; agent host A's requests and token never are, and robot
    host r2 can neither announce a daemon that is not its own nor answer for r1's."""
    _, s, _ = fleet
    asked: list[bytes] = []
    real = s["r1"].declare_queryable(
        "hosts/r1/rpc/*", lambda q: (asked.append(q.payload.to_bytes()), q.reply(q.key_expr, ok_reply(who="r1")))
    )
    rogue = s["r2"].declare_queryable("hosts/r1/rpc/*", lambda q: q.reply(q.key_expr, ok_reply(who="r2")))
    tokens = [s["r2"].liveliness().declare_token("hosts/r9"), s["r1"].liveliness().declare_token("hosts/r1")]
    try:
        seen = wait_until(lambda: _tokens(s["op"], "hosts/*") or None, 20, "r1's daemon token at the operator")
        assert seen == ["hosts/r1"], f"host daemons seen by the operator: {seen}"

        def operator_heard() -> bool:
            for who, payload in (("hostA", b"agents"), ("op", b"operator")):
                replies = [
                    decode_map(r.ok.payload.to_bytes())["who"]
                    for r in s[who].get("hosts/r1/rpc/launch", payload=payload, timeout=3)
                    if r.ok
                ]
                assert who == "op" or replies == [], f"agent host A got answers {replies}"
                if who == "op":
                    assert replies in ([], ["r1"]), f"the operator's launch answered by {replies}"
            return asked.count(b"operator") >= 3

        wait_until(operator_heard, 30, "the operator's launch requests at r1's daemon", interval=0.05)
        assert b"agents" not in asked, "an agent host's launch request reached the daemon"
        runners = [s[n].liveliness().declare_token(f"hosts/r1/run/{n}/runner") for n in ("hostA", "op")]
        try:
            got = wait_until(lambda: _tokens(s["r1"], "hosts/r1/run/*/runner") or None, 20, "the operator's runner")
            assert got == ["hosts/r1/run/op/runner"], f"launcher tokens seen by r1's daemon: {got}"
        finally:
            for t in runners:
                t.undeclare()
    finally:
        for x in (real, rogue, *tokens):
            x.undeclare()


def test_a_secured_run_launches_on_the_robot_hosts_daemon_and_an_agent_host_cannot(fleet, tmp_path):
    """``rsal host`` as robot host r1 (its agent hosts as agent host A), ``rsal run`` as the operator:
    A's agent hunter-1 is launched on r1's daemon and its outcome ends the run; the same run as
    agent host A does not even see the daemon (one line, exit 1)."""
    f, _, _ = fleet
    host_cfg = tmp_path / "host.toml"
    host_cfg.write_text(f'[agents]\nconfig = "{f.member_config("hostA")}"\n')
    scenario = tmp_path / "s.yaml"
    scenario.write_text(
        "scenario: secured\n"
        "agent_types: {rep: tests.agents.scenario_agents:Reporter}\n"
        "applications:\n"
        "  a:\n"
        "    agents: [{type: rep, id: hunter-1, machine: r1, args: {subjects: [r0], every: 0.3}}]\n"
        "    end: {event: caught, count: 1, timeout: 60}\n"
    )
    daemon = Proc(
        rsal_cmd("host", "--name", "r1", "--config", str(f.member_config("r1")), "--host-config", str(host_cfg))
    )
    try:
        wait_until(lambda: "up: token hosts/r1" in daemon.output() or not daemon.alive(), 30, "r1's daemon")
        assert daemon.alive(), daemon.output()
        run = Proc(rsal_cmd("run", str(scenario), "--config", str(f.member_config("op"))))
        try:
            wait_until(lambda: not run.alive(), 90, "the operator's run to end")
            out = run.output()
            assert run.p.returncode == 0, out
            assert "[run] launched hunter-1 on machine r1" in out and "[run] result: ok — " in out, out
        finally:
            run.close()
        assert "launched run" in daemon.output()
        run = Proc(rsal_cmd("run", str(scenario), "--config", str(f.member_config("hostA"))))
        try:
            wait_until(lambda: not run.alive(), 60, "agent host A's run to give up")
            out = run.output()
            assert run.p.returncode == 1, out
            assert "rsal run: machine 'r1' (host group hunter-1): no host daemon hosts/r1 on the fabric" in out, out
        finally:
            run.close()
        assert daemon.output().count("launched run") == 1
    finally:
        daemon.close()


def test_only_the_operator_may_command_the_simulators_crowd():
    """The crowd device's cmd moves every robot of a simulator: only a role that may command every
    robot's position2d may put it (the operator); an agent host given robots, a robot host of other
    nodes and a viewer get no rule that covers it."""
    from rsal.secure import acl

    key = zenoh.KeyExpr("rsal/sim/crowd/0/cmd")
    idents = [
        Identity("simhost", "robot", nodes=["sim", "r0", "r1"]),
        Identity("r2", "robot", nodes=["r2"]),
        Identity("hostA", "agents", agents=["swarm0"], services=["send_position"], robots=["r0", "r1"]),
        Identity("op", "operator"),
        Identity("view", "viewer"),
    ]
    table = acl(idents)
    rules = {r["id"]: r for r in table["rules"]}

    def may_put(name: str) -> bool:
        ids = next(p["rules"] for p in table["policies"] if p["subjects"] == [name])
        return any(
            "put" in rules[i]["messages"]
            and rules[i]["flows"] == ["ingress"]
            and any(zenoh.KeyExpr(k).intersects(key) for k in rules[i]["key_exprs"])
            for i in ids
        )

    assert may_put("op")
    assert may_put("simhost")  # the simulator's own host serves (and may drive) its nodes
    assert not may_put("hostA") and not may_put("r2") and not may_put("view")
