"""AMCL on a replay localizes as on the live robot (``rsal record`` + ``rsal play``, Player's readlog).

Live: ``rsal sim maps/testroom.world --truth`` (at the suite's speed-up; ``--truth`` adds
``r0:position2d:3``, the ground-truth pose) and ``rsal serve deploy/testroom-replay-amcl.toml``
(AMCL on the map bitmap, started 0.3 m and 11 degrees uncertain) while this process drives r0 on a
circle and ``rsal record`` records the odometry, the laser and the ground truth. Then everything
stops, and a fresh ``rsal serve`` of the same file localizes on ``rsal play`` of the recording
(started ``--paused``, resumed by the control device's rpc once AMCL is up). Both estimates are
judged against the recorded ground truth, matched by the simulated time ``t`` the estimate belongs
to.
"""

from __future__ import annotations

import json
import math
import threading
import time

import msgpack
import numpy as np
import zenoh

from rsal.record import Recording
from tests.conftest import ROOT, SPEEDUP, Proc, free_port, rsal_cmd, wait_until

WORLD = str(ROOT / "maps" / "testroom.world")
AMCL = str(ROOT / "deploy" / "testroom-replay-amcl.toml")
DRIVE_S = 25.0  # simulated seconds of driving
CONVERGED_S = 8.0  # the estimates from this long after the first one are judged
CMD = {"v": 0.3, "w": 0.25}  # a circle of 1.2 m radius around (-2, 1.2): clear of the walls and the box


def session(*, listen: str | None = None, connect: str | None = None) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps([listen]))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps([connect]))
    return zenoh.open(conf)


def tokens(s: zenoh.Session) -> set[str]:
    return {str(r.ok.key_expr) for r in s.liveliness().get("rsal/**", timeout=1.0) if r.ok}


class Series:
    """(t, x, y) of every message on one key."""

    def __init__(self, s: zenoh.Session, key: str):
        self.rows: list[tuple[float, float, float]] = []
        self._lock = threading.Lock()
        self.sub = s.declare_subscriber(key, self._on)

    def _on(self, smp) -> None:
        m = msgpack.unpackb(smp.payload.to_bytes())
        with self._lock:
            self.rows.append((m["t"], m["pose"][0], m["pose"][1]))

    def array(self) -> np.ndarray:
        with self._lock:
            return np.array(self.rows, dtype=float).reshape(-1, 3)


def errors(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Each converged estimate's distance to the true pose at its time (truth every sim step)."""
    est = est[est[:, 0] >= est[0, 0] + CONVERGED_S]
    order = np.argsort(truth[:, 0])
    truth = truth[order]
    i = np.clip(np.searchsorted(truth[:, 0], est[:, 0]), 1, len(truth) - 1)
    i = np.where(np.abs(truth[i - 1, 0] - est[:, 0]) < np.abs(truth[i, 0] - est[:, 0]), i - 1, i)
    assert np.all(np.abs(truth[i, 0] - est[:, 0]) < 0.06), "a true pose within half a step of every estimate"
    return np.hypot(est[:, 1] - truth[i, 1], est[:, 2] - truth[i, 2])


def test_amcl_localizes_on_a_replay_as_on_the_live_robot(tmp_path):
    run = tmp_path / "run.mcap"
    ep = f"tcp/127.0.0.1:{free_port()}"
    started: list[Proc] = []
    try:
        # ------------------------------------------------------------ live, recorded
        started.append(Proc(rsal_cmd("sim", WORLD, "--truth", "--no-map", "--speedup", SPEEDUP, "--listen", ep)))
        started.append(Proc(rsal_cmd("serve", AMCL, "--connect", ep)))
        with session(connect=ep) as s:
            want = {"rsal/r0/laser/0", "rsal/r0/position2d/0", "rsal/r0/position2d/3", "rsal/r0/localize/0"}
            wait_until(lambda: want <= tokens(s), 90, "the simulated robot, its ground truth and live AMCL")
            truth_live = Series(s, "rsal/r0/position2d/3/data")
            live = Series(s, "rsal/r0/localize/0/data")
            templates = ("r0:position2d:0", "r0:position2d:3", "r0:laser:0")
            rec = Proc(rsal_cmd("record", *templates, "-o", str(run), "--connect", ep))
            started.append(rec)
            wait_until(lambda: "3 devices" in rec.output(), 30, "the recorder to see the three devices")
            wait_until(lambda: len(truth_live.array()) > 0, 10, "ground truth")
            t_end = truth_live.array()[-1, 0] + DRIVE_S
            cmd = msgpack.packb(CMD)
            while truth_live.array()[-1, 0] < t_end:  # commands at 20 Hz: within any cmd_timeout
                s.put("rsal/r0/position2d/0/cmd", cmd)
                time.sleep(0.05)
            s.put("rsal/r0/position2d/0/cmd", msgpack.packb({"v": 0.0, "w": 0.0}))
            time.sleep(0.5)
            assert rec.stop() == 0, rec.output()
            live_est, live_truth = live.array(), truth_live.array()
        for p in started:
            p.close()
        started.clear()
        # ------------------------------------------------------------ replayed
        recorded = Recording(run)
        truth = np.array(
            [
                (m["t"], m["pose"][0], m["pose"][1])
                for m in (msgpack.unpackb(x.data) for x in recorded.samples() if x.key == "rsal/r0/position2d/3/data")
            ]
        )
        assert len(truth) > 0.9 * DRIVE_S * 10, "the ground truth of every step is in the recording"
        path = np.hypot(*np.diff(truth[:, 1:], axis=0).T).sum()
        assert path > 0.8 * CMD["v"] * DRIVE_S, f"the robot drove its circle ({path:.1f} m)"
        ep2 = f"tcp/127.0.0.1:{free_port()}"
        with session(listen=ep2) as s:
            started.append(Proc(rsal_cmd("serve", AMCL, "--connect", ep2)))
            play = Proc(rsal_cmd("play", str(run), "--connect", ep2, "--paused", "--rate", "1"))
            started.append(play)
            wait_until(lambda: "rsal/r0/localize/0" in tokens(s), 60, "AMCL on the replayed devices")
            est = Series(s, "rsal/r0/localize/0/data")
            replies = [r for r in s.get("rsal/play/player/0/rpc/resume", timeout=5.0) if r.ok]
            assert len(replies) == 1
            play.p.wait(DRIVE_S / float(SPEEDUP) + 60)
            assert play.p.returncode == 0, play.output()
            time.sleep(0.5)  # the last estimates in flight
            replay_est = est.array()
    finally:
        for p in started:
            p.close()
    assert len(replay_est) >= 20 and len(live_est) >= 20, (len(replay_est), len(live_est))
    e_replay, e_live = errors(replay_est, truth), errors(live_est, live_truth)
    print(
        f"amcl error after {CONVERGED_S:g} s: replay mean {e_replay.mean():.3f} max {e_replay.max():.3f} m "
        f"({len(e_replay)} estimates); live mean {e_live.mean():.3f} max {e_live.max():.3f} m ({len(e_live)})"
    )
    assert e_live.max() < 0.3, "the live reference localizes"
    assert e_replay.max() < 0.3, f"replay: {e_replay.max():.3f} m off the recorded ground truth"
    assert abs(e_replay.mean() - e_live.mean()) < 0.1, "the replay localizes as well as the live run"
    # the replay covered the drive: estimates over the whole recorded span
    assert replay_est[-1, 0] - replay_est[0, 0] >= 0.9 * DRIVE_S
    assert math.isfinite(replay_est[:, 1:].sum())
