"""``features info`` of a set a stopped ``features build`` left incomplete names the command
that finishes it (the same build again), as it does for damaged or stale windows."""

from __future__ import annotations

import contextlib
import json
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.config_sources import ENV_PREFIX


@pytest.mark.slow
def test_an_incomplete_set_names_the_build_that_finishes_it(
    small_flight: Callable[..., Path],
    engine_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    from c3_matcher.cli import main
    from c3_matcher_tools.features import build

    flight = small_flight("stopped")
    monkeypatch.setenv(f"{ENV_PREFIX}ENGINES__DIRECTORY", str(engine_dir))
    real_task, calls = build.task, []

    def stopped(*args: Any) -> Any:  # Ctrl-C once the first window is stored
        calls.append(args)
        if len(calls) == 2:
            with contextlib.suppress(KeyboardInterrupt):
                signal.raise_signal(signal.SIGINT)
        return real_task(*args)

    monkeypatch.setattr(build, "task", stopped)
    argv = ["features", "build", str(flight), "--strategy", "xfeat", "--workers", "0"]
    assert main([*argv, "--flight-candidates", "--batch", "1"]) == 130
    capsys.readouterr()
    assert main(["features", "info", str(flight), "--verify", "--json"]) == 0
    (found,) = json.loads(capsys.readouterr().out)["sets"]
    assert found["complete"] is False
    assert found["command"] is not None
    assert found["command"].startswith("c3-matcher features build ")
    assert "--strategy xfeat" in found["command"]
