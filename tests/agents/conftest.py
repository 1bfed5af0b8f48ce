"""Fixtures of the agent layer's tests."""

from __future__ import annotations

import pytest

from tests.agents.browser import open_browser
from tests.conftest import LoopThread, free_port


@pytest.fixture
def browser_page():
    """``browser_page(width, height) -> (page, errors)``: a page of headless chromium
    (tests/agents/browser.py); skips where there is no browser to drive."""
    yield from open_browser()


@pytest.fixture
def hosts():
    """Two agent hosts on their own Zenoh sessions over loopback (one listens, one connects) and the
    loop thread that runs them: ``(loop_thread, receiving host, sending host)``."""
    from agents.runtime import AgentHost
    from rsal.transport import TransportArgs, open_session

    ep = f"tcp/127.0.0.1:{free_port()}"
    s_recv = open_session(TransportArgs(listen=[ep]))
    s_send = open_session(TransportArgs(connect=[ep]))
    lt = LoopThread()
    recv, send = AgentHost(s_recv), AgentHost(s_send)
    lt.run(recv.__aenter__())
    lt.run(send.__aenter__())
    yield lt, recv, send
    lt.run(recv.stop())
    lt.run(send.stop())
    lt.close()
    s_send.close()
    s_recv.close()
