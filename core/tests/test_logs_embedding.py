"""A program embedding the matcher gets each of the matcher's records once on stderr, at the
level it configured, and keeps its own loguru output (run in a fresh interpreter: loguru's
import-time handler is process state)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.compose import compose_root
from c3_matcher.config import C3Settings
from c3_matcher.plugins import PluginHost
from c3_matcher.testing import (
    fake_helpers,
    one_strategy_host,
    pipeline_strategy,
)

PROGRAM = textwrap.dedent(
    """
    from loguru import logger
    from c3_matcher.logs import configure_logging, log_event

    logger.info("host before")
    handle = configure_logging(None, level="INFO")
    log_event("DEBUG", "c3.test.debug", "matcher debug")
    log_event("INFO", "c3.test.info", "matcher info")
    logger.info("host during")
    handle.close()
    logger.info("host after")
    handle = configure_logging(None, level="INFO")  # composed again: still once
    log_event("INFO", "c3.test.again", "matcher again")
    handle.close()
    """
)


def test_each_matcher_record_once_at_the_configured_level() -> None:
    proc = subprocess.run(
        [sys.executable, "-c", PROGRAM], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    ours = [line for line in lines if "matcher " in line]
    assert len(ours) == 2, proc.stderr  # once each, as JSON; the DEBUG record not at all
    assert [json.loads(x)["kind"] for x in ours] == ["c3.test.info", "c3.test.again"]
    for host in ("host before", "host during", "host after"):  # the program's own, in text
        assert sum(host in line for line in lines) == 1, proc.stderr


def _fake_host() -> PluginHost:
    return one_strategy_host("fake", pipeline_strategy())


@pytest.mark.parametrize("configured", [False, True])
def test_the_default_fdr_path_is_stated_when_used(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, logs: Any, configured: bool
) -> None:
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))  # the default lands in tmp
    fdr = {"path": tmp_path / "mine.jsonl"} if configured else {}
    root = compose_root(
        C3Settings(matcher={"strategy": "fake"}, fdr=fdr),
        fake_helpers(),
        plugin_host=_fake_host(),
        configure_logs=False,
    )
    try:
        stated = logs.of_kind("c3.fdr.default_path")
        if configured:
            assert stated == []
        else:
            assert len(stated) == 1 and stated[0]["path"] == str(root.fdr.path)  # type: ignore[attr-defined]
            assert str(tmp_path / "data") in stated[0]["path"]
    finally:
        root.close()


HELPERS_FIRST = textwrap.dedent(
    """
    from loguru import logger
    from c3_matcher.compose import build_default_helpers
    from c3_matcher.config import C3Settings

    logger.info("host before")
    build_default_helpers(C3Settings())  # logs the inference provider it picks
    logger.info("host after")
    """
)


def test_building_the_helpers_before_compose_root_prints_no_plain_text_matcher_line() -> None:
    """The README's order (helpers, then ``compose_root``): the matcher's records stay off
    loguru's plain-text default handler, the program's own still reach it."""
    proc = subprocess.run(
        [sys.executable, "-c", HELPERS_FIRST], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert "inference provider" not in proc.stderr, proc.stderr
    assert "host before" in proc.stderr and "host after" in proc.stderr
