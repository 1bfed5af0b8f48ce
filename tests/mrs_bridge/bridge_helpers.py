"""In-process device servers for the mrs_bridge tests: a DeviceServer on its own loopback Zenoh
session (multicast scouting off, explicit tcp/127.0.0.1 endpoints), its scheduler on a thread."""

from __future__ import annotations

import textwrap
import threading

import zenoh

from mrs_bridge.config import ServerConfig, parse_config
from mrs_bridge.driver import Driver
from mrs_bridge.server import DeviceServer
from rsal.transport import TransportArgs, open_session


def loopback(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


class LiveServer:
    """Open the session now; :meth:`start` declares the devices and runs the scheduler thread."""

    def __init__(
        self,
        config_text: str | ServerConfig,
        *,
        port: int,
        connect: tuple[int, ...] = (),
        drivers: dict[str, type[Driver]] | None = None,
        require_timeout: float = 30.0,
        source: str = "test.toml",
        shared: dict | None = None,
    ):
        if isinstance(config_text, ServerConfig):
            self.config = config_text
        else:
            self.config = parse_config(textwrap.dedent(config_text), source=source)
        self.session: zenoh.Session = open_session(
            TransportArgs(listen=[loopback(port)], connect=[loopback(p) for p in connect])
        )
        self.server = DeviceServer(
            self.config, self.session, require_timeout=require_timeout, drivers=drivers, shared=shared
        )
        self.thread: threading.Thread | None = None
        self.error: BaseException | None = None
        self._closed = False

    def start(self) -> LiveServer:
        self.server.start()
        self.thread = threading.Thread(target=self._run, name="device-server", daemon=True)
        self.thread.start()
        return self

    def _run(self) -> None:
        try:
            self.server.run()
        except BaseException as e:  # kept for the test to inspect
            self.error = e

    def driver(self, name: str) -> Driver:
        """The driver of the block with this name (the first one)."""
        return next(s.driver for s in self.server.slots if s.driver.cfg.name == name)

    def slot_state(self, name: str) -> str:
        return next(s.state for s in self.server.slots if s.driver.cfg.name == name)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.server.stop()
        if self.thread is not None:
            self.thread.join(10)
            assert not self.thread.is_alive(), "the server's scheduler did not stop"
        self.server.close()
        self.session.close()
