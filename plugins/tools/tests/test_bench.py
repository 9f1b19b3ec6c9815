"""``c3-matcher bench``: the ratios it reports (stored vs extracted tiles,
adaptive vs full LightGlue, vs the PyTorch reference) from synthetic results, and a smoke run
end to end (XFeat, one timed run per case) over a flight whose store has features built."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.bench import (
    BenchCase,
    comparisons,
    format_report,
    stored_features_path,
)

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"


def _result(case: BenchCase, p50: float, rss: float = 100.0) -> dict[str, Any]:
    from dataclasses import asdict

    return {
        "case": asdict(case),
        "label": case.label,
        "provider": "CPUExecutionProvider",
        "runs": 1,
        "startup_s": 0.1,
        "best_inliers": 100,
        "frame_ms": {"p50": p50, "p95": p50 * 1.1},
        "per_candidate_ms": {"p50": p50 / 3, "p95": p50 / 3},
        "stages_ms": {"extract": {"p50": 1.0, "p95": 2.0}},
        "feature_sources": (
            {"stored": 3}
            if case.stored_features
            else {"cached": 2, "extracted": 1}
            if case.tile_cache_size
            else {"extracted": 3}
        ),
        "peak_rss_mib": rss,
    }


def test_comparisons_are_speedups_of_the_right_pairs() -> None:
    s = "disk_lightglue"
    results = [
        _result(BenchCase(s, "engine", 0, 1024, None), 1000.0),
        _result(BenchCase(s, "engine", 16, 1024, None), 500.0),
        _result(BenchCase(s, "engine", 0, 1024, None, True), 400.0),
        _result(BenchCase(s, "engine", 0, 1024, None, False, "full"), 3000.0),
        _result(BenchCase(s, "pytorch", 0, 1024, None), 5000.0, rss=900.0),
    ]
    got = {c["comparison"]: c for c in comparisons(results)}
    assert got["cached vs new tiles"]["speedup_p50"] == pytest.approx(2.0)
    assert got["stored features vs extraction"]["speedup_p50"] == pytest.approx(2.5)
    assert got["adaptive vs full LightGlue"]["speedup_p50"] == pytest.approx(3.0)
    vs_torch = got[f"{results[0]['label']} vs PyTorch"]
    assert vs_torch["speedup_p50"] == pytest.approx(5.0)
    assert vs_torch["peak_rss_mib"] == (100.0, 900.0)
    text = format_report({"machine": _machine(), "runs": 1, "data": "x", "results": results})
    assert "stored features vs extraction: 2.50x p50" in text
    assert "adaptive vs full LightGlue: 3.00x p50" in text
    assert "stored 3/3" in text and "vs torch" in text
    row = next(line for line in text.splitlines() if line.startswith(results[0]["label"]))
    assert row.split()[len(results[0]["label"].split())] == "CPU"  # not cut to CPUExecutionProvid


def _machine() -> dict[str, Any]:
    return {
        "platform": "test",
        "cpus": 2,
        "onnxruntime": "0",
        "available_providers": ["CPUExecutionProvider"],
    }


@pytest.mark.slow
def test_bench_smoke_over_a_flight_with_stored_features(
    engine_dir: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from c3_matcher.cli import main
    from c3_matcher.config import load_settings
    from c3_matcher_tools.features.build import build_features, flight_windows

    flight = tmp_path / "naip_demo"
    shutil.copytree(FLIGHT, flight)
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    windows = flight_windows(flight, 32)  # the windows of the flight's candidates
    build_features(
        flight / "tiles.mbtiles",
        ["xfeat"],
        load_settings(None),
        window_px=448,
        stride_px=32,
        windows=windows,
        workers=0,
    )
    assert stored_features_path(flight) is not None
    argv = ["bench", "--runs", "1", "--strategy", "xfeat", "--no-baseline", "--no-reference"]
    assert main([*argv, "--data", str(flight)]) == 0
    out = capsys.readouterr().out
    assert "xfeat (stored tiles" in out and "xfeat (new tiles" in out
    assert "stored features vs extraction:" in out and "cached vs new tiles:" in out
    assert "peak MiB" in out and "stored 3/3" in out  # the stored case really used the store


def test_bench_data_defaults_to_the_checkouts_demo_frame_and_is_required_from_wheels(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from c3_matcher.engines import store
    from c3_matcher_tools.bench import demo_data

    assert demo_data(FLIGHT) == FLIGHT
    assert demo_data(None) == REPO / "data" / "demo"
    assert (demo_data(None) / "demo.json").is_file()
    monkeypatch.setattr(store, "checkout_root", lambda: None)  # as installed from wheels
    with pytest.raises(InvalidInputError, match="--data: required"):  # exit 2: bad input
        demo_data(None)


@pytest.mark.parametrize("argv", [["--runs", "0"], ["--runs", "-3"], ["--threads", "0"]])
def test_a_count_below_one_is_a_usage_error_naming_the_option(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    with pytest.raises(SystemExit) as stop:  # refused while parsing: no case runs
        main(["bench", *argv, "--data", str(FLIGHT)])
    err = capsys.readouterr().err.strip()
    assert stop.value.code == 2 and len(err.splitlines()) == 1, err
    assert f"{argv[0]}: must be >= 1, got {argv[1]}" in err


def _garbage_store(flight: Path) -> Path:
    (flight / "tiles.mbtiles").write_text("garbage\n")
    return flight


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (lambda root: root / "missing", "--data: no such directory: "),
        (lambda root: root, "neither a flight dataset (dataset.json) nor a demo-format"),
        (lambda root: _garbage_store(shutil.copytree(FLIGHT, root / "f")), "not an SQLite"),
    ],
    ids=["missing", "neither", "garbage-store"],
)
def test_data_that_cannot_be_benched_is_refused_before_any_case_runs(
    data: Callable[[Path], Path], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    path = data(tmp_path)
    assert main(["bench", "--runs", "1", "--data", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and str(path) in err and len(err.splitlines()) == 1, err


def test_the_worker_refuses_fewer_than_one_run() -> None:
    import io

    from c3_matcher_tools.bench_worker import _worker_main

    with pytest.raises(SystemExit) as stop:
        _worker_main(["{}", "0", str(FLIGHT)], io.StringIO(), io.StringIO())
    assert stop.value.code == 2


def test_a_tile_source_that_served_nothing_is_not_compared() -> None:
    """A cached case whose frames share no tile extracted every tile, like the new-tiles case:
    its ratio would be noise, so the report says why there is none."""
    s = "disk_lightglue"
    cached = _result(BenchCase(s, "engine", 16, 1024, None), 900.0)
    cached["feature_sources"] = {"extracted": 3}
    stale = _result(BenchCase(s, "engine", 0, 1024, None, True), 950.0)
    stale["feature_sources"] = {"extracted": 3}
    results = [_result(BenchCase(s, "engine", 0, 1024, None), 1000.0), cached, stale]
    got = {c["comparison"]: c for c in comparisons(results)}
    assert "speedup_p50" not in got["cached vs new tiles"]
    assert "from the cache" in got["cached vs new tiles"]["not_compared"]
    assert "from the store" in got["stored features vs extraction"]["not_compared"]
    text = format_report({"machine": _machine(), "runs": 1, "data": "x", "results": results})
    assert "cached vs new tiles: not compared: no tile features came from the cache" in text


def test_a_candidates_time_is_every_stage_it_went_through() -> None:
    """Stored features cost their assembly, a refined best its second pass: both count in the
    per-candidate time and are listed as stages."""
    from types import SimpleNamespace

    from c3_matcher_tools.bench_worker import summary, timed_match

    result = SimpleNamespace(
        per_candidate=(SimpleNamespace(inlier_count=80),),
        diagnostics={
            "candidate_features": ["stored"],
            "timings_ms": {"query_preprocess": 1.0, "query_extract": 2.0},
            "per_candidate_timings_ms": [
                {"assemble": 3.0, "match": 40.0, "ransac": 5.0, "refine": 50.0}
            ],
        },
    )
    matcher = SimpleNamespace(match=lambda *_: result)
    timed = summary([timed_match(matcher, [(None, None, None)], 0)])
    assert timed["per_candidate_ms"]["p50"] == pytest.approx(98.0)
    assert timed["stages_ms"]["assemble"]["p50"] == 3.0 and "refine" in timed["stages_ms"]
