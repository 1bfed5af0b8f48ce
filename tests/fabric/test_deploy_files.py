"""The driver configurations shipped in ``deploy/`` load, and each one the docs show is the same file."""

from __future__ import annotations

import re

import pytest

from tests.conftest import ROOT

DEPLOY = sorted((ROOT / "deploy").glob("*.toml"))
DOCS = [ROOT / "docs" / "configuration.md", ROOT / "docs" / "navigation.md"]


def doc_blocks() -> dict[str, str]:
    """``deploy/NAME.toml`` -> the TOML block the docs show for it (first line ``# deploy/NAME.toml``)."""
    out = {}
    for doc in DOCS:
        for block in re.findall(r"```toml\n(.*?)```", doc.read_text(), re.S):
            m = re.search(r"#\s*(deploy/[\w.-]+\.toml)", block)
            if m:
                out.setdefault(m.group(1), block)
    return out


def test_there_are_deploy_configs():
    assert len(DEPLOY) >= 5


@pytest.mark.parametrize("path", DEPLOY, ids=lambda p: p.name)
def test_deploy_config_loads(path):
    from mrs_bridge.config import load_config

    cfg = load_config(path)
    assert cfg.drivers


def test_docs_show_the_shipped_files():
    blocks = doc_blocks()
    assert blocks, "the docs name no deploy/ files"
    for name, block in blocks.items():
        f = ROOT / name
        assert f.exists(), f"{name} is shown in the docs but not shipped"
        assert f.read_text().strip() == block.strip(), f"{name} differs from the docs"
