"""Driver parameters as dataclasses (mrs_bridge/params.py): every rule once, with the exact line."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import pytest

from mrs_bridge.config import ConfigError, parse_config
from mrs_bridge.params import describe_params, did_you_mean, param, parse_params

WHERE = "t.toml: driver #1 (x)"


@dataclass(frozen=True)
class P:
    IGNORED: ClassVar[tuple[str, ...]] = ("alwayson",)

    port: str = param(doc="the serial device", example="/dev/ttyS0")
    baud: Literal[9600, 115200] = param(9600)
    mode: Literal["fast", "slow"] = param("fast")
    count: int | None = param(None, min=1)
    timeout: float = param(1.0, min=0.2, max=30.0, unit="seconds")
    speed: float = param(0.5, gt=0.0, lt=2.0)
    gain: float = param(1.0, finite=False)
    pose: tuple[float, float, float] = param((0.0, 0.0, 0.0))
    names: tuple[str, ...] = param(())
    flag: bool = param(False)
    file: Path | None = param(None)
    global_: bool = param(False)
    anything: Any = param(None)

    def __post_init__(self) -> None:
        if self.flag and self.count is None:
            raise ValueError("flag = true needs count")


def parse(text: str, **kw):
    cfg = parse_config(
        f'[[driver]]\nname = "x"\nprovides = ["r0:laser:0"]\n{text}', source="t.toml", base_dir=Path("/cfg")
    )
    return parse_params(P, cfg.drivers[0], **kw)


def error(text: str) -> str:
    with pytest.raises(ConfigError) as ei:
        parse(text)
    msg = str(ei.value)
    assert msg.startswith(WHERE + ": ") and "\n" not in msg
    return msg[len(WHERE) + 2 :]


def test_defaults_types_and_coercion():
    p = parse('port = "/dev/a"\ntimeout = 2\npose = [1, 2, 3]\nnames = "r1"\nfile = "m.png"\nglobal = true')
    assert (p.port, p.baud, p.mode, p.count, p.timeout, p.flag, p.global_) == (
        "/dev/a",
        9600,
        "fast",
        None,
        2.0,
        False,
        True,
    )
    assert isinstance(p.timeout, float) and p.pose == (1.0, 2.0, 3.0) and p.names == ("r1",)
    assert p.file == Path("/cfg/m.png")  # relative to the config file
    assert parse('port = "/dev/a"\ngain = inf').gain == float("inf")


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", "needs 'port', the serial device (e.g. port = \"/dev/ttyS0\")"),
        ('port = "a"\nbuad = 9600', "unknown parameter 'buad'; did you mean 'baud'?"),
        ('port = "a"\nzzz = 1', "unknown parameter 'zzz'; known: port, baud, mode, count, timeout, speed, gain,"),
        ('port = "a"\nbaud = 1200', "baud = 1200 must be one of 9600, 115200"),
        ('port = "a"\nmode = "fsat"', "mode = 'fsat' must be one of fast, slow; did you mean 'fast'?"),
        ('port = "a"\ncount = 0', "count = 0 must be an integer >= 1"),
        ('port = "a"\ncount = 1.5', "count = 1.5 must be an integer >= 1"),
        ('port = "a"\ncount = true', "count = True must be an integer >= 1"),
        ('port = "a"\ntimeout = 0', "timeout = 0 must be a number of seconds in [0.2, 30]"),
        ('port = "a"\ntimeout = "x"', "timeout = 'x' must be a finite number of seconds in [0.2, 30]"),
        ('port = "a"\nspeed = 2', "speed = 2 must be a number in (0, 2)"),
        ('port = "a"\nspeed = nan', "speed = nan must be a finite number in (0, 2)"),
        ('port = "a"\npose = [1, 2]', "pose = [1, 2] must be a list of 3 numbers"),
        ('port = "a"\nnames = [1]', "names = [1] must be a list of strings"),
        ('port = "a"\nflag = 1', "flag = 1 must be true or false"),
        ("port = 5", "port = 5 must be a string"),
        ('port = "a"\nflag = true', "flag = true needs count"),
    ],
)
def test_each_mistake_is_one_line_with_the_key_and_a_fix(text, expected):
    assert error(text).startswith(expected)


def test_ignored_player_options_are_logged_and_dropped(caplog):
    caplog.set_level(logging.WARNING)
    parse('port = "a"\nalwayson = 1', log=logging.getLogger("t"))
    assert any("'alwayson' has no effect here" in r.message for r in caplog.records)


def test_rest_hands_unknown_keys_on():
    p, rest = parse('port = "a"\npf_max_samples = 5', rest=True)
    assert p.port == "a" and rest == {"pf_max_samples": 5}


def test_did_you_mean_and_the_table_for_docs():
    assert did_you_mean("mapfiel", ["mapfile", "sim"]) == "mapfile" and did_you_mean("q", ["mapfile"]) is None
    rows = {r["name"]: r for r in describe_params(P)}
    assert rows["port"]["required"] and rows["global"]["type"] == "bool"
    assert rows["timeout"]["expect"] == "a number of seconds in [0.2, 30]"
