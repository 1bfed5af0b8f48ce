"""Fixtures of the agent layer's tests."""

from __future__ import annotations

import pytest

from tests.agents.browser import open_browser


@pytest.fixture
def browser_page():
    """``browser_page(width, height) -> (page, errors)``: a page of headless chromium
    (tests/agents/browser.py); skips where there is no browser to drive."""
    yield from open_browser()
