"""``eval`` reads each strategy's flight-data log once, the largest file a run leaves: the
candidates counted by where their features came from (its flight report, its ``eval.json`` entry)
and the set a store served none of (the line that says so) come from that one pass
(:func:`~c3_matcher_tools.run.feature_sources.read_feature_sources`). On a two-frame cut of the
demo flight with real XFeat engines, and on a log written by the real recorder."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

import c3_matcher_tools.run.feature_sources as feature_sources
from c3_matcher.fdr import JsonlFdrRecorder, read_fdr_log
from c3_matcher.health import MonotonicClock
from c3_matcher_tools.run.feature_sources import FDR_LOG, read_feature_sources

SmallFlight = Callable[..., Path]  # the fixture of conftest.py
UNSERVED = "c3.matcher.stored_features_unserved"


@pytest.fixture()
def reads(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """Every flight-data log the feature sources read, one entry a pass over it."""
    passes: list[Path] = []

    def counted(path: Path) -> Iterator[Any]:
        passes.append(Path(path))
        return read_fdr_log(path)

    monkeypatch.setattr(feature_sources, "read_fdr_log", counted)
    return passes


def test_eval_reads_each_strategys_flight_data_log_once(
    small_flight: SmallFlight,
    engine_dir: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    reads: list[Path],
) -> None:
    from c3_matcher.cli import main

    flight = small_flight("two_frames")
    out = tmp_path / "out"
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    argv = ["eval", str(flight), "--strategy", "xfeat", "--out", str(out)]
    assert main([*argv, "--determinism-frames", "1", "--samples", "0"]) == 0
    assert sorted(reads) == [out / "sift_magsac" / FDR_LOG, out / "xfeat" / FDR_LOG]
    entries = {e["strategy"]: e for e in json.loads((out / "eval.json").read_text())["strategies"]}
    xfeat = entries["xfeat"]["feature_sources"]  # what the one pass counted
    assert xfeat["extracted"] + xfeat["cached"] == entries["xfeat"]["timing"]["candidates"] > 0


def test_one_pass_gives_the_counts_and_the_set_a_store_did_not_serve(
    tmp_path: Path, reads: list[Path]
) -> None:
    log = tmp_path / FDR_LOG
    recorder = JsonlFdrRecorder(log, MonotonicClock())
    unserved = {"kind": UNSERVED, "asked_set_id": "xfeat:a:x2", "held_set_ids": ["xfeat:a"]}
    recorder.record("log.warning", unserved)
    recorder.record("matcher.frame_done", {"candidate_features": ["extracted", "cached"]})
    recorder.record("log.warning", {**unserved, "asked_set_id": "a later one"})
    recorder.record("matcher.insufficient_inliers", {"candidate_features": ["extracted"]})
    recorder.close()
    sources = read_feature_sources(log)
    assert sources.counts == {"stored": 0, "cached": 1, "extracted": 2}
    assert sources.unserved == ("xfeat:a:x2", ("xfeat:a",))  # the first warning's
    assert reads == [log]
    missing = read_feature_sources(tmp_path / "none" / FDR_LOG)
    assert missing.counts == {"stored": 0, "cached": 0, "extracted": 0}
    assert missing.unserved is None
