"""A run's ``run.json`` names the dataset it ran on (resolved path) and replay's strategy, and
says ``running`` until its files are written: the default output directory, named after the
dataset's name, is never silently given to another dataset of that name, and a run killed
before it ended is told from one that ended (the ``sift_magsac`` baseline, two frames)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.cli import main
from c3_matcher_tools.run.run_mark import RUN_MARK

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
QUICK = ("--determinism-frames", "1", "--samples", "0")


@pytest.mark.parametrize(
    ("command", "default"),
    [
        (["replay", "--limit", "1"], Path("out/replay/same-sift_magsac")),
        (["eval", "--no-baseline", *QUICK], Path("out/eval/same")),
    ],
)
def test_the_default_out_of_one_dataset_is_refused_to_another_of_its_name(
    small_flight: SmallFlight,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    command: list[str],
    default: Path,
) -> None:
    first, second = small_flight("same", where="a"), small_flight("same", where="b")
    monkeypatch.chdir(tmp_path)
    verb, *options = command

    def run(flight: Path) -> int:
        return main([verb, str(flight), "--strategy", "sift_magsac", *options])

    assert run(first) == 0
    assert run(first) == 0  # a rerun of the same dataset replaces its own
    capsys.readouterr()
    results = sorted((tmp_path / default).rglob("results.jsonl"))
    before = {p: p.read_bytes() for p in results}
    assert run(second) == 2
    said = capsys.readouterr().err
    assert f"--out: {default} holds a {verb} of {first}, another dataset named 'same'" in said
    assert f"than this one ({second}): give --out to keep both, or remove {default}" in said
    assert {p: p.read_bytes() for p in results} == before
    mark = json.loads((tmp_path / default / RUN_MARK).read_text())
    assert mark["dataset"] == str(first) and "running" not in mark
    assert main([verb, str(second), "--strategy", "sift_magsac", *options, "--out", "b_out"]) == 0


def test_a_replay_is_marked_running_until_its_files_are_written(
    small_flight: SmallFlight, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import c3_matcher_tools.geojson

    flight, out = small_flight("two_frames"), tmp_path / "out"
    seen: list[Any] = []
    write = c3_matcher_tools.geojson.write_geojson

    def watched(*args: Any, **kwargs: Any) -> Path:
        seen.append(json.loads((out / RUN_MARK).read_text()))  # as the map is written
        return write(*args, **kwargs)

    monkeypatch.setattr(c3_matcher_tools.geojson, "write_geojson", watched)
    assert main(["replay", str(flight), "--strategy", "sift_magsac", "--out", str(out)]) == 0
    mark = {
        "command": "c3-matcher replay",
        "dataset": str(flight),
        "name": "two_frames",
        "strategy": "sift_magsac",
    }
    assert seen == [{**mark, "running": True}]
    assert json.loads((out / RUN_MARK).read_text()) == mark
