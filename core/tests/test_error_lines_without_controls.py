"""A refusal's line on stderr shows a hostile name's control characters as escapes: no line the
command prints can move the terminal's cursor or retitle it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path


def _stderr(*argv: str, cwd: Path) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "c3_matcher.cli", *argv],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 2, done.stderr
    return done.stderr


def test_a_refused_path_with_an_escape_is_said_escaped(tmp_path: Path) -> None:
    said = _stderr("fdr", "no\x1b[2Ksuch\x07.jsonl", cwd=tmp_path)
    assert "\x1b" not in said and "\x07" not in said, said
    assert "no\\x1b[2Ksuch\\x07.jsonl" in said, said


def test_a_usage_error_with_an_escape_is_said_escaped(tmp_path: Path) -> None:
    said = _stderr("match", "--height", "1\x1b]0;pwned\x07", cwd=tmp_path)
    assert "\x1b" not in said and "\x07" not in said, said
