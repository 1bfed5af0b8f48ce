"""The headless browser of the control page's tests: Debian's ``chromium`` (``/usr/bin/chromium``,
installed by ``./dev.sh test``'s set-up; no browser download) driven by the ``playwright`` package.
The ``browser_page`` fixture (tests/agents/conftest.py) opens pages in it; :func:`save_screenshot`
keeps what a page showed."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

__all__ = ["CHROMIUM", "FLAGS", "ensure_chromium", "open_browser", "save_screenshot"]

CHROMIUM = "/usr/bin/chromium"
FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def ensure_chromium() -> None:
    """Debian's chromium at /usr/bin/chromium, installed by the test command's set-up (``./dev.sh test``);
    where it is missing the test skips and says how to install it."""
    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} is missing: ./dev.sh test installs it as root, or run apt-get install chromium")


def open_browser() -> Iterator[Callable[[int, int], tuple]]:
    """Start headless chromium and yield ``open_page(width, height) -> (page, errors)``, ``errors``
    the list the page's script errors go to; the browser closes when the generator does. Skips,
    with the reason, where playwright or chromium is missing or chromium cannot start."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install -e .[test])")
    ensure_chromium()
    with sync_api.sync_playwright() as pw:
        try:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        except Exception as e:  # a chromium that cannot start here: say why
            pytest.skip(f"{CHROMIUM} does not start headless: {' '.join(str(e).split())[:300]}")

        def open_page(width: int, height: int) -> tuple:
            page = browser.new_page(viewport={"width": width, "height": height})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            return page, errors

        try:
            yield open_page
        finally:
            browser.close()


def save_screenshot(page, tmp_path: Path, name: str) -> Path:
    """The whole page as ``tmp_path/name``, copied to ``$RSAL_ARTIFACTS`` when that is set."""
    path = tmp_path / name
    page.screenshot(path=str(path), full_page=True)
    if os.environ.get("RSAL_ARTIFACTS"):
        out = Path(os.environ["RSAL_ARTIFACTS"])
        out.mkdir(parents=True, exist_ok=True)
        shutil.copy(path, out / name)
    return path
