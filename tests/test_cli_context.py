"""Every command handler receives one ``CommandContext`` (settings, plugin host, streams): the
plugins are discovered once per process, whatever the command; the configured pixel limit
reaches the images the command reads, as a value it is given (no process-wide state)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "data" / "demo"


@pytest.fixture
def discoveries(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts the plugin discoveries of this process from now on."""
    import c3_matcher.compose as compose

    calls: list[int] = []
    real = compose.discover

    def counting() -> Any:
        calls.append(1)
        return real()

    monkeypatch.setattr(compose, "discover", counting)
    return calls


@pytest.mark.parametrize("argv", [["plugins", "--json"], ["engines", "list", "--json"]])
def test_a_command_discovers_the_plugins_once(
    argv: list[str],
    discoveries: list[int],
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from c3_matcher.cli import main

    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(tmp_path))
    assert main(argv) == 0
    assert len(discoveries) == 1
    json.loads(capsys.readouterr().out)  # the result on the context's stdout, one JSON value


def test_the_handler_gets_the_context_the_command_line_built(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import c3_matcher.cli as cli
    from c3_matcher.context import CommandContext

    seen: list[CommandContext] = []

    def record(args: Any, ctx: CommandContext) -> int:
        seen.append(ctx)
        ctx.out("result")
        ctx.err("progress")
        return 0

    monkeypatch.setattr(cli, "_cmd_config", record)
    monkeypatch.setenv("C3_MATCHER_MATCHER__MIN_INLIERS_THRESHOLD", "77")
    assert cli.main(["config"]) == 0
    (ctx,) = seen
    assert ctx.settings.matcher.min_inliers_threshold == 77
    assert "xfeat" in ctx.plugin_host.strategies()
    out = capsys.readouterr()
    assert (out.out, out.err.splitlines()[-1]) == ("result\n", "progress")


def test_the_configured_pixel_limit_refuses_a_larger_query(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main
    from c3_matcher.tiles import read_image

    monkeypatch.setenv("C3_MATCHER_MATCHER__MAX_IMAGE_PIXELS", "1000")
    argv = ["match", "--query", str(DEMO / "frame.jpg"), "--tile", str(DEMO / "tile_a.png")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "frame.jpg" in err and "exceeds the limit of 1000 px" in err
    assert read_image(DEMO / "frame.jpg").ndim == 3  # the limit stayed with that command


def test_match_gives_back_its_flight_data_record_when_the_strategy_cannot_be_composed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main
    from c3_matcher.fdr import JsonlFdrRecorder
    from c3_matcher.health import MonotonicClock

    fdr = tmp_path / "fdr.jsonl"
    query, tile = str(DEMO / "frame.jpg"), str(DEMO / "tile_a.png")
    argv = ["match", "--query", query, "--tile", tile, "--strategy", "no_such_strategy"]
    assert main([*argv, "--fdr", str(fdr)]) == 2
    assert "no_such_strategy" in capsys.readouterr().err
    JsonlFdrRecorder(fdr, MonotonicClock()).close()  # one writer per path: it was closed
