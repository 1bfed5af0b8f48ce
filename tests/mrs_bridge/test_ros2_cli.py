"""``rsal ros2`` and ``rsal rosbag2``: every user error is one line on stderr and exit code 1 or 2
(argparse), before anything connects."""

from __future__ import annotations

from contextlib import nullcontext

import pytest

from rsal.cli import main


@pytest.mark.parametrize(
    ("argv", "env", "code", "line"),
    [
        (
            ["ros2"],
            {"ROS_DOMAIN_ID": "x"},
            1,
            "rsal ros2: ROS_DOMAIN_ID='x' is not an integer from 0 to 232; fix it or pass --domain N",
        ),
        (
            ["ros2", "--domain", "300"],
            {},
            2,
            "argument --domain: '300' must be a ROS domain id, an integer from 0 to 232",
        ),
        (
            ["ros2", "--robots", "r/0"],
            {},
            2,
            "argument --robots: 'r/0': give robot names or patterns separated by commas",
        ),
        (
            ["ros2", "--frame-prefix", "{ns}/"],
            {},
            1,
            "rsal ros2: --frame-prefix '{ns}/' may only use {robot}, e.g. '{robot}/'",
        ),
        (
            ["ros2", "--node-name", "a-b"],
            {},
            1,
            "rsal ros2: --node-name 'a-b' is not a ROS node name (letters, digits, _)",
        ),
        (["ros2", "--map-node", "a/b"], {}, 1, "rsal ros2: --map-node 'a/b' is not a node name or pattern"),
        (["rosbag2", "nope.mcap", "-o", "bag"], {}, 1, "nope.mcap: no such file"),
    ],
)
def test_user_errors_are_one_line(argv, env, code, line, capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    with pytest.raises(SystemExit) if code == 2 else nullcontext():
        rc = main(argv)
        assert rc == code
    err = capsys.readouterr().err.strip().splitlines()
    assert line in err[-1], err
    assert not any("Traceback" in e for e in err)
