"""The default engine directory is one place per installation, whatever the working directory:
a source checkout's ``.engines`` (where ``scripts/demo`` and ``engines build`` put them)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from c3_matcher.engines.store import EngineStore, checkout_root, default_engine_dir
from c3_matcher.errors import EngineError

REPO = Path(__file__).resolve().parents[2]


def test_checkout_default_is_the_checkouts_engines() -> None:
    assert checkout_root() == REPO
    assert default_engine_dir() == REPO / ".engines"


def test_cli_finds_the_same_directory_from_anywhere(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("C3_MATCHER_")}
    exe = Path(sys.executable).with_name("c3-matcher")
    proc = subprocess.run(
        [str(exe), "config", "--json"], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["engines"]["directory"] == str(REPO / ".engines")


def test_missing_engine_says_where_it_looked_and_what_fixes_it(tmp_path: Path) -> None:
    with pytest.raises(EngineError) as err:
        EngineStore(tmp_path).require("disk", "depth")
    text = str(err.value)
    assert str(tmp_path) in text
    assert "c3-matcher engines build --only disk/depth" in text
    assert "C3_MATCHER_ENGINES__DIRECTORY" in text
