"""The host daemon's wire: the requests ``rsal run`` sends to ``rsal host`` and what a launched agent
host sends back (thesis 3.6.1: Jadex started an application's agents on any
platform of the network, outlook: agents started on the robots' own computers).

Keys (:mod:`rsal.keys`; ``docs/protocol.md``, "Host daemons")::

    liveliness token hosts/<name>          the daemon is up and answers
    hosts/<name>/rpc/launch|stop|status    requests (query), replies ok or a typed error
    hosts/<name>/run/<run>/out             one output line of the launched agent host (:class:`OutLine`)
    hosts/<name>/run/<run>/exit            its end (:class:`RunExit`), put once
    liveliness token hosts/<name>/run/<run>/runner   the launcher: when it goes, the run is stopped

A :class:`LaunchRequest` carries the scenario file's *text* (hosts share no file system), the
application, the host group and the ``--set`` overrides; the daemon runs
``python -m agents.hostproc COPY --remote --app APP --host GROUP ...`` for it. Every payload is a
msgpack map through :mod:`rsal.msgs`' codec and field readers, checked on decode
(:class:`rsal.msgs.MessageError` names the field).
"""

from __future__ import annotations

from dataclasses import dataclass

from rsal.keys import check_name
from rsal.msgs import MessageError, _Msg, get_bool, get_float, get_int, get_list, get_str

__all__ = ["SUFFIXES", "LaunchRequest", "OutLine", "RunExit", "StopRequest"]

#: the scenario formats a launch may carry (the suffix tells the daemon's loader which)
SUFFIXES = (".yaml", ".yml", ".toml")
#: the largest scenario text a daemon takes (a scenario file is a few kB)
MAX_SCENARIO = 256 * 1024


def _name(m: dict, field: str) -> str:
    v = get_str(m, field)
    try:
        return check_name(field, v)
    except ValueError as e:
        raise MessageError(f"field {field!r}: {e}") from None


@dataclass(frozen=True)
class LaunchRequest(_Msg):
    """Start the agents of host group ``group`` of application ``app`` of the scenario ``scenario``
    (the file's text; ``suffix`` its format), with ``overrides`` (``--set KEY=VALUE`` items).
    ``sim_clock`` names the simulation node whose clock the agents follow (``RSAL_SIM_TIME``), or "".
    """

    run: str
    app: str
    group: str
    scenario: str
    suffix: str = ".yaml"
    overrides: tuple[str, ...] = ()
    report_every: float = 30.0
    sim_clock: str = ""

    @classmethod
    def from_dict(cls, m: dict) -> LaunchRequest:
        run, app, group, text = _name(m, "run"), get_str(m, "app"), get_str(m, "group"), get_str(m, "scenario")
        if len(text) > MAX_SCENARIO:
            raise MessageError(f"field 'scenario' is {len(text)} characters, over the {MAX_SCENARIO} a daemon takes")
        overrides = get_list(m, "overrides", lambda x: x if isinstance(x, str) else _bad("overrides"), False)
        return cls(
            run=run,
            app=app,
            group=group,
            scenario=text,
            suffix=get_str(m, "suffix", ".yaml", choices=SUFFIXES),
            overrides=tuple(overrides),
            report_every=get_float(m, "report_every", 30.0, lo=0.01),
            sim_clock=get_str(m, "sim_clock", ""),
        )


def _bad(field: str):
    raise MessageError(f"field {field!r} must be a list of strings")


@dataclass(frozen=True)
class StopRequest(_Msg):
    """Stop run ``run`` (SIGTERM to its agent host, SIGKILL after the daemon's deadline)."""

    run: str

    @classmethod
    def from_dict(cls, m: dict) -> StopRequest:
        return cls(run=_name(m, "run"))


@dataclass(frozen=True)
class OutLine(_Msg):
    """One line the launched agent host wrote; ``err`` for its standard error; ``seq`` counts from 0."""

    seq: int
    line: str
    err: bool = False

    @classmethod
    def from_dict(cls, m: dict) -> OutLine:
        return cls(seq=get_int(m, "seq", lo=0), line=get_str(m, "line"), err=get_bool(m, "err", False))


@dataclass(frozen=True)
class RunExit(_Msg):
    """The launched agent host ended: its exit ``code`` (negative: the signal that ended it) and
    ``reason``, one line (how it ended and its last error line)."""

    code: int
    reason: str

    @classmethod
    def from_dict(cls, m: dict) -> RunExit:
        return cls(code=get_int(m, "code"), reason=get_str(m, "reason", ""))
