"""The ``amcl`` driver (mrs_bridge/drivers/amcl.py) against an in-memory fake server: hypotheses
clustered only for a ``localize`` message that goes out, and known obstacles declared by command
(``cmd``, :class:`ObstaclesCmd`) as by ``rpc/set_obstacles``.

Map: a 6 m x 4 m room (0.1 m cells) with walls on its border, origin (0, 0); a 19-beam laser.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mrs_bridge.config import parse_config
from mrs_bridge.drivers.amcl import AmclDriver
from rsal import interfaces
from rsal.interfaces.localize import LocalizeData, ObstaclesCmd
from rsal.msgs import MapData, MessageError, Position2dData, RangerData
from rsal.testing import FakeServer

CONFIG = """
[[driver]]
name = "amcl"
provides = ["r0:localize:0", "r0:position2d:2"]
requires = ["odometry::r0:position2d:0", "r0:laser:0", "r0:map:0"]
init_pose = [3.0, 2.0, 0]
init_pose_var = [0.05, 0.05, 5]
pf_min_samples = 100
pf_max_samples = 500
seed = 7
"""


def room() -> dict:
    cells = np.full((40, 60), -1, dtype=np.int8)
    cells[0, :] = cells[-1, :] = cells[:, 0] = cells[:, -1] = 1
    return MapData(60, 40, 0.1, (0.0, 0.0), cells).to_dict()


def _scan(t: float) -> dict:
    # from (3, 2) facing +x: the walls' distances over -90..90 deg (a 6 x 4 m room, walls 0.1 m thick)
    b = np.linspace(-math.pi / 2, math.pi / 2, 19)
    with np.errstate(divide="ignore"):
        dx = np.where(np.cos(b) > 1e-9, 2.9 / np.cos(b), np.inf)
        dy = np.where(np.abs(np.sin(b)) > 1e-9, 1.9 / np.abs(np.sin(b)), np.inf)
    r = np.minimum(dx, dy).astype(np.float32)
    return RangerData(t, r, -math.pi / 2, math.pi / 18, 0.02, 5.0).to_dict()


@pytest.fixture
def driver():
    cfg = parse_config(CONFIG, source="amcl.toml").drivers[0]
    srv = FakeServer()
    drv = AmclDriver(cfg, srv)
    drv.on_reply(cfg.requires[2], "get", room(), None)
    drv.on_reply(cfg.requires[1], "describe", {"geometry": {"pose": [0, 0, 0], "sensors": [{"pose": [0, 0, 0]}]}}, None)
    assert drv.ready()
    drv.on_input(cfg.requires[0], "data", Position2dData(1.0, (0.0, 0.0, 0.0), (0, 0, 0)).to_dict())
    return drv, srv


def _localize(srv) -> list[LocalizeData]:
    return [m for a, m in srv.published if a == "r0:localize:0"]


def test_hypotheses_are_clustered_only_for_a_localize_message_that_goes_out(driver, monkeypatch):
    drv, srv = driver
    calls = []
    real = type(drv.filter).hypotheses
    monkeypatch.setattr(type(drv.filter), "hypotheses", lambda f: calls.append(1) or real(f))
    srv.unheard.add("r0:localize:0")  # nobody subscribes to localize:0
    srv.published.clear()
    drv.on_input(drv.cfg.requires[1], "data", _scan(1.0))
    assert drv.updates == 1
    assert not _localize(srv) and not calls  # no message, no clustering
    assert [a for a, _ in srv.published] == ["r0:position2d:2"]  # the map-frame pose still goes out
    srv.unheard.clear()  # someone subscribes: the next localize message carries the hypotheses
    drv._publish_localize(1.1)
    drv._publish_localize(1.2)
    assert len(calls) == 1  # clustered once per filter update, however many messages go out
    (m, m2) = _localize(srv)
    assert m.hypotheses == m2.hypotheses


def test_lazily_clustered_hypotheses_equal_those_of_the_filter_at_its_update(driver):
    drv, srv = driver
    drv.on_input(drv.cfg.requires[1], "data", _scan(1.0))
    assert drv.updates == 1
    (m,) = _localize(srv)
    want = drv.filter.hypotheses()[:8]  # the same seeded filter, clustered again now
    assert len(m.hypotheses) == len(want) >= 1
    for h, (w, mean, cov) in zip(m.hypotheses, want, strict=True):
        assert h.weight == pytest.approx(min(1.0, w))
        assert h.pose == pytest.approx(tuple(mean))
        assert h.cov == pytest.approx(tuple(cov.ravel()))
    assert math.hypot(m.hypotheses[0].pose[0] - 3.0, m.hypotheses[0].pose[1] - 2.0) < 0.3


def test_known_obstacles_declared_by_command_take_effect_and_expire(driver):
    drv, _ = driver
    loc = drv.cfg.provides[0]
    kinds = interfaces.cmd_types("localize")
    assert kinds == (ObstaclesCmd,)
    cmd = interfaces.decode_as(kinds, {"obstacles": [[4.0, 2.0, 0.4], [2.0, 3.0, 0.4]], "ttl": 0.5})
    drv.on_cmd(loc, cmd)
    assert drv.filter.obstacles.tolist() == [[4.0, 2.0, 0.4], [2.0, 3.0, 0.4]]
    drv.on_input(drv.cfg.requires[1], "data", _scan(1.4))  # within the ttl: still declared
    assert drv.filter.obstacles.shape[0] == 2
    drv.on_input(drv.cfg.requires[1], "data", _scan(1.6))  # 0.6 s after the declaration
    assert drv.filter.obstacles.shape[0] == 0
    with pytest.raises(MessageError, match="takes no commands"):  # the map-frame pose takes none
        drv.on_cmd(drv.cfg.provides[1], cmd)


@pytest.mark.parametrize(
    ("m", "why"),
    [
        ({"obstacles": [[1.0, 2.0]]}, r"'obstacles'\[0\]"),
        ({"obstacles": [[1.0, 2.0, -0.4]]}, r"radius > 0"),
        ({"obstacles": "near"}, "list of"),
        ({"obstacles": [], "ttl": 0}, "ttl"),
    ],
)
def test_a_malformed_obstacles_command_is_refused_in_decoding_naming_the_field(m, why):
    with pytest.raises(MessageError, match=why):
        interfaces.decode_as(interfaces.cmd_types("localize"), m)
