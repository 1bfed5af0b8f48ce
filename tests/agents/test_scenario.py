"""Unit tests of scenario files (thesis fig. 3.11, application files) and agent-host specs.

The loader turns a YAML or TOML file into frozen dataclasses; every kind of mistake is one
:class:`ScenarioError` line naming the file, the key path and a fix. ``check_classes`` resolves the
agent classes and their arguments before anything starts; ``constructor_kwargs`` passes the global
arguments a constructor accepts and always the entry's own. No network, no processes.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from agents.hostproc import HostError, build_agent, host_agents
from agents.scenario import (
    DEFAULT_TIMEOUT,
    AgentEntry,
    ScenarioError,
    check_classes,
    constructor_kwargs,
    load_scenario,
    parse_set,
)
from tests.agents.scenario_agents import Reporter
from tests.conftest import MAPS, ROOT

GOOD = """
scenario: demo
description: a demo
arguments: {report_every: 1.0, startup_timeout: 5}
agent_types:
  prey: EscapeAgent
  hunter: WallfollowAgent
  reporter: tests.agents.scenario_agents:Reporter
applications:
  virtual:
    description: all simulated
    simulator: {world: WORLD, nav: vfh, nav_robots: [r0], speedup: 2, threads: 1}
    agents:
      - {type: prey, robot: r0}
      - {type: hunter, robot: "r{i}", count: 3, id: "hunter{i}", host: hunters}
      - {type: reporter}
      - {type: reporter, args: {event: delivered, subjects: [b1, b2]}}
    end: {event: caught, count: 2, timeout: 60}
  plain:
    agents:
      - {type: reporter, id: rep}
    end: {duration: 10}
"""


def write(tmp_path: Path, text: str, name: str = "s.yaml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text).replace("WORLD", str(MAPS / "testroom.world")))
    return p


def error(tmp_path: Path, text: str, name: str = "s.yaml") -> str:
    p = write(tmp_path, text, name)
    with pytest.raises(ScenarioError) as e:
        load_scenario(p)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(str(p)), msg
    return msg


def test_good_file_loads_into_dataclasses(tmp_path):
    sc = load_scenario(write(tmp_path, GOOD))
    assert sc.name == "demo" and sc.arguments == {"report_every": 1.0, "startup_timeout": 5}
    app = sc.applications["virtual"]
    assert app.simulator.world == (MAPS / "testroom.world").resolve()
    assert app.simulator.nav == "vfh" and app.simulator.nav_robots == ("r0",) and app.simulator.speedup == 2
    assert app.simulator.threads == 1
    ids = [a.id for a in app.agents]
    assert ids == ["prey-r0", "hunter0", "hunter1", "hunter2", "reporter0", "reporter1"]
    assert [a.robot for a in app.agents[1:4]] == ["r0", "r1", "r2"]
    assert app.agents[1].cls == "WallfollowAgent" and app.agents[1].host == "hunters"
    assert app.agents[5].args == {"event": "delivered", "subjects": ["b1", "b2"]}
    groups = app.groups()
    assert list(groups) == ["prey-r0", "hunters", "reporter0", "reporter1"]
    assert [a.id for a in groups["hunters"]] == ["hunter0", "hunter1", "hunter2"]
    assert app.end.event == "caught" and app.end.count == 2 and app.end.timeout == 60 and app.end.duration is None
    plain = sc.applications["plain"]
    assert plain.simulator is None and plain.servers == ()
    assert plain.end.duration == 10 and plain.end.event is None and plain.end.timeout >= DEFAULT_TIMEOUT


def test_toml_has_the_same_structure(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text(
        textwrap.dedent(
            """
            scenario = "t"
            [agent_types]
            rep = "tests.agents.scenario_agents:Reporter"
            [applications.one]
            agents = [{type = "rep", count = 2, id = "rep{i}"}]
            end = {event = "caught", count = 1}
            """
        )
    )
    sc = load_scenario(p)
    assert [a.id for a in sc.applications["one"].agents] == ["rep0", "rep1"]
    assert sc.applications["one"].end.timeout == DEFAULT_TIMEOUT


def test_set_overrides_global_arguments(tmp_path):
    over = parse_set(["report_every=2", "laser=no", "name=r0", "xs=[1, 2]"])
    assert over == {"report_every": 2, "laser": False, "name": "r0", "xs": [1, 2]}
    sc = load_scenario(write(tmp_path, GOOD), over)
    assert sc.arguments["report_every"] == 2 and sc.arguments["startup_timeout"] == 5 and sc.arguments["laser"] is False
    for bad in ("report_every", "=3", "2x=1"):
        with pytest.raises(ScenarioError, match="KEY=VALUE"):
            parse_set([bad])


def test_an_empty_file_and_files_that_do_not_parse(tmp_path):
    assert "the file is empty" in error(tmp_path, "")
    assert "applications: must be a non-empty map" in error(
        tmp_path, "scenario: x\nagent_types: {a: B}\napplications: []"
    )
    assert "not valid YAML" in error(tmp_path, "scenario: [x\n")
    assert "not valid TOML" in error(tmp_path, "scenario = \n", "s.toml")


def test_missing_files_are_named_relative_to_the_scenario(tmp_path):
    msg = error(tmp_path, GOOD.replace("WORLD", "nowhere.world"))
    assert "simulator.world: file 'nowhere.world' does not exist (paths are relative to the scenario file)" in msg
    msg = error(tmp_path, GOOD.replace("  plain:\n", "  plain:\n    servers: [r0.toml]\n"))
    assert "applications.plain.servers[0]: file 'r0.toml' does not exist" in msg
    (tmp_path / "r0.toml").write_text("")
    sc = load_scenario(write(tmp_path, GOOD.replace("  plain:\n", "  plain:\n    servers: [r0.toml]\n")))
    assert sc.applications["plain"].servers == ((tmp_path / "r0.toml").resolve(),)
    with pytest.raises(ScenarioError, match="cannot read the scenario file"):
        load_scenario(tmp_path / "absent.yaml")


def test_check_classes_resolves_classes_and_arguments(tmp_path):
    sc = load_scenario(write(tmp_path, GOOD))
    check_classes(sc, sc.applications["virtual"])
    bad = load_scenario(write(tmp_path, GOOD.replace("hunter: WallfollowAgent", "hunter: HunterAgent")))
    with pytest.raises(ScenarioError) as e:
        check_classes(bad, bad.applications["virtual"])
    assert "agent_types.hunter: unknown agent class 'HunterAgent'" in str(e.value)
    check_classes(bad, bad.applications["plain"])  # the plain application does not use hunters
    bad = load_scenario(write(tmp_path, GOOD.replace("subjects: [b1, b2]", "subject: [b1, b2]")))
    with pytest.raises(ScenarioError) as e:
        check_classes(bad, bad.applications["virtual"])
    assert "agent reporter1: args.subject: Reporter takes no argument 'subject'; did you mean 'subjects'?" in str(
        e.value
    )
    bad = load_scenario(write(tmp_path, GOOD.replace("scenario_agents:Reporter", "scenario_agents:Nobody")))
    with pytest.raises(ScenarioError, match="has no Agent subclass 'Nobody'"):
        check_classes(bad, bad.applications["plain"])


def test_constructor_kwargs_filters_only_global_arguments():
    from agents.classes import WallfollowAgent

    glob = {"report_every": 2.0, "laser": False, "fleet_size": 3}
    kw = constructor_kwargs(WallfollowAgent, "r0", glob, {"period": 0.2})
    assert kw == {"report_every": 2.0, "laser": False, "robot": "r0", "period": 0.2}
    kw = constructor_kwargs(Reporter, "", glob, {"event": "x", "bogus": 1})
    assert kw == {"robot": "", "event": "x", "bogus": 1}  # entry args always passed ...
    with pytest.raises(HostError, match=r"agent rep \(Reporter\):.*bogus"):  # ... and rejected by the class
        build_agent(AgentEntry("rep", "tests.agents.scenario_agents:Reporter", "rep", "", {"bogus": 1}), glob)


HOSTS = """
scenario: hosts
arguments: {laser: false}
agent_types: {wf: WallfollowAgent, rep: tests.agents.scenario_agents:Reporter}
applications:
  two:
    agents:
      - {type: wf, robot: r0, id: a, host: h, args: {period: 0.2}}
      - {type: rep, id: b}
      - {type: rep, id: c, host: h}
    end: {event: x}
"""


def test_a_host_builds_its_agents_from_the_parsed_scenario(tmp_path):
    sc = load_scenario(write(tmp_path, HOSTS))
    entries = host_agents(sc, "two", "h")
    assert entries == sc.applications["two"].groups()["h"]
    assert [e.id for e in entries] == ["a", "c"] and [e.id for e in host_agents(sc, "two", "b")] == ["b"]
    agent = build_agent(entries[0], sc.arguments)
    assert type(agent).__name__ == "WallfollowAgent" and agent.robot == "r0" and agent.laser is False
    assert agent.period == 0.2
    over = load_scenario(write(tmp_path, HOSTS), parse_set(["laser=true"]))  # rsal run's --set, passed on
    assert build_agent(host_agents(over, "two", "h")[0], over.arguments).laser is True
    with pytest.raises(HostError, match=r"no application 'one'; use one of two"):
        host_agents(sc, "one", "h")
    with pytest.raises(HostError, match=r"application 'two' has no host group 'x'; its groups: h, b"):
        host_agents(sc, "two", "x")
    with pytest.raises(HostError, match="unknown agent class 'Nope'"):
        build_agent(AgentEntry("a", "Nope", "a"))


def test_the_demo_scenario_is_valid():
    sc = load_scenario(ROOT / "deploy" / "scenarios" / "wander.yaml")
    for app in sc.applications.values():
        check_classes(sc, app)
        assert app.simulator.world == (MAPS / "testroom.world").resolve()
        assert app.end.duration == 20


def test_constructor_arguments_are_read_down_the_mro_through_kwargs():
    from agents.classes import WallfollowAgent
    from agents.scenario import _accepts, constructor_kwargs
    from agents.scenarios.hunt import EscapeAgent

    base, open_base = _accepts(WallfollowAgent)
    names, open_ = _accepts(EscapeAgent)  # (agent_id, *, speed, spin_rate, **kw) -> RobotAgent's
    assert not open_ and not open_base
    assert names == base | {"speed", "spin_rate"}
    kw = constructor_kwargs(EscapeAgent, "r0", {"index": 1, "report_every": 2.0, "unknown_global": 3}, {"speed": 0.2})
    assert kw == {"robot": "r0", "index": 1, "report_every": 2.0, "speed": 0.2}
    agent = EscapeAgent("prey", **kw)
    assert (agent.index, agent.report_every, agent.speed) == (1, 2.0, 0.2)


REHEARSED = """
scenario: mixed
agent_types: {reporter: tests.agents.scenario_agents:Reporter}
applications:
  mixed:
    simulator: {world: WORLD}
    rehearse: {world: WORLD, robot: r0, nav: vfh, laser: UTM-30LX}
    agents:
      - {type: reporter, robot: r0}
    end: {event: delivered}
"""


def test_a_rehearse_section_names_the_real_world_and_the_robot_it_waits_for(tmp_path):
    app = load_scenario(write(tmp_path, REHEARSED)).applications["mixed"]
    r = app.rehearse
    assert r.world == (MAPS / "testroom.world").resolve() and r.robot == "r0" and r.nav == "vfh"
    assert r.laser == "UTM-30LX" and r.pioneer is None and r.node == "world" and r.seed is None
    assert r.devices == ("r0/position2d/0", "r0/laser/0", "world/simulation/0", "r0/planner/0")
    plain = load_scenario(write(tmp_path, REHEARSED.replace(", nav: vfh", ""))).applications["mixed"]
    assert plain.rehearse.devices == ("r0/position2d/0", "r0/laser/0", "world/simulation/0")
    assert load_scenario(write(tmp_path, GOOD)).applications["virtual"].rehearse is None
    found = load_scenario(ROOT / "deploy" / "scenarios" / "find_collect.yaml").applications["mixed"]
    assert found.rehearse.robot == "c1" and found.rehearse.world.name == "mixed_real_collect.world"


def test_hosts_spreads_a_count_over_that_many_host_groups_in_blocks(tmp_path):
    sc = load_scenario(write(tmp_path, GOOD.replace("host: hunters}", "host: hunters, hosts: 2}")))
    app = sc.applications["virtual"]
    assert [a.host for a in app.agents[1:4]] == ["hunters0", "hunters0", "hunters1"]
    groups = app.groups()
    assert [a.id for a in groups["hunters0"]] == ["hunter0", "hunter1"]
    assert [a.id for a in groups["hunters1"]] == ["hunter2"]
    assert "hunters" not in groups
    one = load_scenario(write(tmp_path, GOOD.replace("host: hunters}", "host: hunters, hosts: 1}"), "one.yaml"))
    assert {a.host for a in one.applications["virtual"].agents[1:4]} == {"hunters"}


# ---------------------------------------------------------------------------- one-line mistakes
def _row(base: str, old: str, new: str, *expect: str, id: str):
    return pytest.param(base, old, new, expect, id=id)


G, R = "GOOD", "REHEARSED"
MISTAKES = [
    # unknown keys suggest the near one
    _row(G, "agent_types:", "agent_type:", "agent_type: unknown key; did you mean 'agent_types'?", id="key-top"),
    _row(
        G,
        "{type: prey, robot: r0}",
        "{type: prey, robto: r0}",
        "applications.virtual.agents[0].robto: unknown key; did you mean 'robot'?",
        id="key-agent",
    ),
    _row(G, "end: {duration: 10}", "end: {duraton: 10}", "applications.plain.end.duraton", "'duration'", id="key-end"),
    _row(G, "nav: vfh", "nva: vfh", "simulator.nva: unknown key; did you mean 'nav'?", id="key-simulator"),
    # missing required keys
    _row(G, "scenario: demo", "", "the key 'scenario' is missing", id="missing-scenario"),
    _row(G, "    end: {duration: 10}\n", "", "applications.plain: the key 'end' is missing; add it", id="missing-end"),
    # wrong types
    _row(
        G,
        "count: 3",
        "count: three",
        "agents[1].count: must be a whole number, not the string 'three'",
        id="type-count",
    ),
    _row(G, "timeout: 60", "timeout: soon", "end.timeout: must be a number", id="type-timeout"),
    _row(G, "speedup: 2", "speedup: -1", "simulator.speedup: must be a positive number", id="type-speedup"),
    _row(G, "threads: 1", "threads: -1", "simulator.threads: must be at least 0", id="type-threads"),
    _row(G, "nav: vfh", "nav: astar", "unknown local planner 'astar'; use one of vfh, nd, snd", id="type-nav"),
    # unknown agent type
    _row(
        G,
        "{type: prey, robot: r0}",
        "{type: pray, robot: r0}",
        "agents[0].type: unknown agent type 'pray'; did you mean 'prey'?",
        id="agent-type",
    ),
    # duplicate agent ids and robots
    _row(
        G,
        "{type: reporter}",
        "{type: reporter, id: hunter1}",
        "agent id 'hunter1' is used twice (also by applications.virtual.agents[1])",
        id="dup-id",
    ),
    _row(G, 'id: "hunter{i}"', "id: hunter", "3 agents cannot share id 'hunter'", id="dup-count-id"),
    _row(G, 'robot: "r{i}"', "robot: r1", "3 agents cannot share robot 'r1'", id="dup-robot"),
    _row(G, "id: rep}", "id: a/b}", "one key chunk", id="id-chunk"),
    # the end needs an event or a duration, and a count of at least one
    _row(
        G,
        "end: {duration: 10}",
        "end: {timeout: 10}",
        "applications.plain.end: needs 'event' (with 'count') or 'duration'",
        id="end-none",
    ),
    _row(
        G,
        "count: 2, timeout: 60",
        "count: 0, timeout: 60",
        "applications.virtual.end.count: must be at least 1, not 0",
        id="end-count",
    ),
    _row(G, "count: 3,", "count: 0,", "agents[1].count: must be at least 1", id="agent-count"),
    _row(
        G,
        "end: {duration: 10}",
        "end: {duration: 10, event: caught}",
        "either 'event' (with 'count') or 'duration', not both",
        id="end-both",
    ),
    _row(
        G,
        "end: {duration: 10}",
        "end: {duration: 10, timeout: 5}",
        "end.timeout: 5 s must be longer than the duration 10 s",
        id="end-timeout",
    ),
    _row(
        G,
        "end: {duration: 10}",
        "end: {duration: 10, count: 2}",
        "end.count: counts outcomes of an 'event'",
        id="end-count-duration",
    ),
    # the rehearse section
    _row(
        R,
        "robot: r0, nav",
        "robt: r0, nav",
        "applications.mixed.rehearse.robt: unknown key; did you mean 'robot'?",
        id="rehearse-key",
    ),
    _row(
        R,
        "robot: r0, nav",
        "nav",
        "applications.mixed.rehearse: the key 'robot' is missing; add it",
        id="rehearse-robot-missing",
    ),
    _row(
        R,
        "laser: UTM-30LX",
        "laser: UTM-30",
        "applications.mixed.rehearse.laser: unknown laser 'UTM-30'; did you mean 'UTM-30LX'?",
        id="rehearse-laser",
    ),
    _row(
        R,
        "laser: UTM-30LX",
        "node: sim",
        "rehearse.node: 'sim' is the virtual simulator's node; name the real world's another",
        id="rehearse-node",
    ),
    _row(R, "robot: r0", "robot: r/0", "rehearse.robot: 'r/0' is no node name", id="rehearse-robot-name"),
    _row(
        R,
        "{world: WORLD}",
        "{world: WORLD, speedup: 3}",
        "applications.mixed.simulator.speedup: the rehearsed real world runs in real time",
        id="rehearse-speedup",
    ),
    _row(
        R,
        "rehearse: {world: WORLD,",
        "rehearse: {world: nowhere.world,",
        "rehearse.world: file 'nowhere.world' does not exist",
        id="rehearse-world",
    ),
    # bad 'hosts' values
    _row(G, "host: hunters}", "host: hunters, hosts: 0}", "agents[1].hosts: must be at least 1, not 0", id="hosts-0"),
    _row(
        G,
        "host: hunters}",
        "host: hunters, hosts: two}",
        "agents[1].hosts: must be a whole number, not the string 'two'",
        id="hosts-two",
    ),
    _row(
        G,
        "host: hunters}",
        "host: hunters, hosts: 4}",
        "agents[1].hosts: 4 agent hosts for 3 agent(s); give at most count (3) hosts",
        id="hosts-too-many",
    ),
    _row(
        G,
        ", host: hunters}",
        ", hosts: 2}",
        "agents[1].hosts: spreads the agents over 2 host groups named after 'host'; add e.g. host: swarm",
        id="hosts-no-host",
    ),
    _row(
        G,
        "host: hunters}",
        'host: "h{i}", hosts: 2}',
        "agents[1].host: with 'hosts' the groups are named 'h{i}' + 0..1; remove '{i}'",
        id="hosts-index",
    ),
    _row(
        G,
        "host: hunters}",
        "host: hunters, hostz: 2}",
        "agents[1].hostz: unknown key; did you mean 'host'?",
        id="hosts-unknown-key",
    ),
]


@pytest.mark.parametrize(("base", "old", "new", "expect"), MISTAKES)
def test_a_mistake_is_one_line_naming_its_place_and_a_fix(tmp_path, base, old, new, expect):
    text = {"GOOD": GOOD, "REHEARSED": REHEARSED}[base]
    assert old in text, f"the edit {old!r} -> {new!r} changes nothing in {base}"
    msg = error(tmp_path, text.replace(old, new)).partition(".yaml: ")[2]  # not the path: it names the test
    for part in expect:
        assert part in msg, (part, msg)


def test_the_swarm_monitor_logs_at_its_own_period_not_the_agents_broadcast_period():
    sc = load_scenario(ROOT / "deploy" / "scenarios" / "swarm.yaml")
    groups = sc.applications["thousand"].groups()
    monitor = next(e for g in groups.values() for e in g if e.id == "monitor")
    swarmer = next(e for g in groups.values() for e in g if e.id == "swarm0")
    assert sc.arguments["report_every"] == 0.5
    assert build_agent(swarmer, sc.arguments).report_every == 0.5
    assert build_agent(monitor, sc.arguments).log_every == 10.0
