"""``c3-matcher bench --data`` on flights the audit found it crashed on, through the real path
(the CLI, its worker processes, the real XFeat engines, flights shipped in ``data/flights``):

- a simulated flight with no frame whose true tile is among its candidates (distractor-only) is
  refused before any case runs: one line, exit 2; a recorded flight without ground truth is
  timed whole;
- a case whose every timed frame raises InsufficientInliersError still reports its frame times
  (the matcher ran) with no candidate time (n/a), instead of a worker traceback;
- peak memory is the worker's own, in MiB, and its key says so (``peak_rss_mib``).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FLIGHTS = REPO / "data" / "flights"
QUICK = ["--strategy", "xfeat", "--no-baseline", "--no-reference", "--no-modes", "--no-stored"]


def _without_truth(src: Path, dst: Path) -> Path:
    """``src`` as a recorded flight (``dataset import``'s output): candidates with only their
    tile id and score, no ``true_tile_present``."""
    shutil.copytree(src, dst)
    rows = [json.loads(line) for line in (dst / "frames.jsonl").read_text().splitlines()]
    for row in rows:
        row.pop("true_tile_present", None)
        row["candidates"] = [
            {"tile_id": c["tile_id"], "score": c["score"]} for c in row["candidates"]
        ]
    (dst / "frames.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return dst


def test_a_flight_with_no_frame_to_time_is_refused_in_one_line_before_any_case(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    path = FLIGHTS / "naip_distractors_s2015"
    assert main(["bench", "--runs", "2", *QUICK, "--data", str(path)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1, err  # no traceback, and no case started
    assert err.startswith("c3-matcher: --data: ") and str(path) in err, err
    assert "none of its 12 frames has its true tile" in err and "no match to time" in err
    assert "bench:" not in err and captured.out == ""


def test_a_recorded_flight_without_ground_truth_times_every_frame(tmp_path: Path) -> None:
    from c3_matcher_tools.dataset.format import load_dataset
    from c3_matcher_tools.run.inputs import flight_inputs

    recorded = _without_truth(FLIGHTS / "naip_demo", tmp_path / "recorded")
    with flight_inputs(recorded) as inputs:
        assert len(inputs) == len(load_dataset(recorded).frames) == 30


@pytest.mark.slow
def test_a_case_whose_every_frame_raises_reports_its_frame_times_and_no_candidate_time(
    engine_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from c3_matcher.cli import main
    from c3_matcher_tools.bench_report import text_report

    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    # XFeat's whole budget (its engine's top-K, 4096): no candidate reaches it, so every frame
    # raises, as every timed frame of naip_cross_date did when the audit ran it (a threshold
    # above the budget is refused at start-up)
    monkeypatch.setenv("C3_MATCHER_MATCHER__MIN_INLIERS_THRESHOLD", "4096")
    data = FLIGHTS / "naip_cross_date"
    ballast = b"x" * (1536 << 20)  # this process holds 1.5 GiB when it starts the workers
    assert main(["bench", "--runs", "2", *QUICK, "--json", "--data", str(data)]) == 0
    del ballast
    report = json.loads(capsys.readouterr().out)
    results = report["results"]
    assert [r["case"]["tile_cache_size"] > 0 for r in results] == [False, True]
    for r in results:
        assert r["frames_raised"] == r["runs"] == 2 and r["best_inliers"] == 0
        assert 0 < r["frame_ms"]["p50"] <= r["frame_ms"]["p95"]  # the raised frames, timed
        assert r["per_candidate_ms"] is None and r["stages_ms"] == {}  # none matched: n/a
        # the worker's own peak, under a key that says MiB: not its parent's (ru_maxrss
        # counts what the parent held when it forked the worker, 4.4 GiB under a test run)
        assert 50 < r["peak_rss_mib"] < 1024 and "peak_rss_mb" not in r
    assert {c["comparison"] for c in report["comparisons"]} == {"cached vs new tiles"}
    text = text_report(report)  # what bench prints without --json
    for r in results:
        row = next(line for line in text.splitlines() if line.startswith(r["label"]))
        assert "n/a" in row.split()  # cand p95
        assert f"note: {r['label']}: 2/2 timed frames raised InsufficientInliersError" in text
    assert text.count("cand p95 and stage times: n/a (none matched)") == 2
    memory = text.replace("GPU memory <= 800 MB", "")  # C3-PT-01's bar, as the spec states it
    assert "peak MiB" in text and " MB" not in memory  # the table and the speed-ups
