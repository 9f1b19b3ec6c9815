"""The run layer: a run's overrides over the configuration, the settings a strategy actually
ran with (its own defaults where the configuration leaves a setting unset), the same flight
flown twice giving the same frames bit for bit, and the feature backend a strategy flies with,
on the real path (xfeat, the first frames of the shipped demo flight)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.config import C3Settings
from c3_matcher.errors import UnknownStrategyError
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run import Overrides, fly, open_backend, write_results

DEMO = Path(__file__).resolve().parents[3] / "data" / "flights" / "naip_demo"


def test_overrides_set_only_what_they_name() -> None:
    settings = C3Settings(matcher={"max_keypoints": 1024, "tile_cache_size": 4})
    assert Overrides().apply(settings) is settings
    got = Overrides(max_keypoints=512, lightglue_mode="full", intra_op_threads=2).apply(
        settings, "xfeat"
    )
    assert (got.matcher.strategy, got.matcher.max_keypoints) == ("xfeat", 512)
    assert got.matcher.tile_cache_size == 4  # not named: as configured
    assert (got.lightglue.mode, got.engines.intra_op_threads) == ("full", 2)
    assert settings.matcher.max_keypoints == 1024  # the configuration itself is left alone


def test_a_flight_run_records_the_settings_it_ran_with_and_repeats_bit_for_bit(
    engine_dir: Path, tmp_path: Path
) -> None:
    from c3_matcher.compose import build_plugin_host

    host = build_plugin_host()
    defaults = host.resolve("xfeat").defaults
    flight = load_dataset(DEMO)
    flight = dataclasses.replace(flight, frames=flight.frames[:2])
    settings = C3Settings(engines={"directory": engine_dir})  # photometric, refit: unset
    runs = [
        fly(settings, "xfeat", flight, tmp_path / f"run{n}", plugin_host=host) for n in range(2)
    ]
    first, second = runs
    assert first.settings["strategy"] == "xfeat"
    assert first.settings["photometric"] == defaults.photometric
    assert first.settings["refit_threshold_px"] == defaults.refit_threshold_px
    assert first.matcher_labels == ["xfeat"]
    assert [o.index for o in first.outcomes] == [f.index for f in flight.frames]
    assert [o.fingerprint for o in first.outcomes] == [o.fingerprint for o in second.outcomes]
    assert first.startup_s < first.wall_s
    lines = write_results(tmp_path / "results.jsonl", first.outcomes).read_text().splitlines()
    assert [json.loads(line)["fingerprint"] for line in lines] == [
        o.fingerprint for o in first.outcomes
    ]
    matched = next(i for i, o in enumerate(first.outcomes) if o.result)
    held = first.outcomes[matched].result["per_candidate"][0]["inlier_correspondences"]
    assert isinstance(held, np.ndarray) and held.dtype == np.float32  # not lists of floats
    written = json.loads(lines[matched])["result"]["per_candidate"][0]
    assert written["inlier_correspondences"] == held.tolist() and len(held) > 0
    assert (tmp_path / "run0" / "fdr.jsonl").stat().st_size > 0


def test_the_backend_a_strategy_flies_with(engine_dir: Path) -> None:
    settings = C3Settings(engines={"directory": engine_dir})
    backend = open_backend(settings, "xfeat", overrides=Overrides(max_keypoints=256))
    assert backend.label == "xfeat"
    assert backend.provenance()["engines"]["extractor"]["file_sha256"]
    assert open_backend(settings, "sift_magsac").label == "sift_magsac"  # the baseline too
    with pytest.raises(UnknownStrategyError, match="no_such_strategy"):
        open_backend(settings, "no_such_strategy")


def test_the_sift_baseline_records_the_keypoint_budget_it_ran_with(
    engine_dir: Path, tmp_path: Path
) -> None:
    """The baseline's row in an eval names its budget as the learned strategies' do (it was
    null: OpenCV SIFT declared none)."""
    from c3_matcher.compose import build_plugin_host
    from c3_matcher.strategy import DEFAULT_MAX_KEYPOINTS

    host = build_plugin_host()
    flight = load_dataset(DEMO)
    flight = dataclasses.replace(flight, frames=flight.frames[:1])
    settings = C3Settings(engines={"directory": engine_dir})
    own = fly(settings, "sift_magsac", flight, tmp_path / "own", plugin_host=host)
    budget = Overrides(max_keypoints=300)
    cut = fly(settings, "sift_magsac", flight, tmp_path / "cut", plugin_host=host, overrides=budget)
    assert (own.keypoint_budget, cut.keypoint_budget) == (DEFAULT_MAX_KEYPOINTS, 300)
    assert not open_backend(settings, "sift_magsac").provenance()["engines"].get("extractor")


def test_flight_inputs_read_tiles_inside_the_block_and_close_the_store_after(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from c3_matcher.tilestore.mbtiles import MBTilesStore
    from c3_matcher_tools.run.inputs import flight_inputs

    closed: list[Path] = []
    close = MBTilesStore.close
    monkeypatch.setattr(MBTilesStore, "close", lambda s: (closed.append(s.path), close(s))[1])
    flight = load_dataset(DEMO)
    with flight_inputs(DEMO) as inputs:
        assert len(inputs) == sum(f.true_tile_present for f in flight.frames)
        frame, rerank, _ = inputs[0]
        assert rerank.frame_id == frame.frame_id
        assert rerank.candidates[0].tile_pixels_handle.decode().ndim == 3
        assert closed == []
    assert len(closed) == 1
    with flight_inputs(DEMO.parents[1] / "demo") as (demo,):  # a demo-format directory
        assert len(demo[1].candidates) == 3


def test_open_matcher_gives_back_its_recorder_and_log_when_composing_fails(
    tmp_path: Path,
) -> None:
    from c3_matcher.fdr import JsonlFdrRecorder
    from c3_matcher.health import MonotonicClock
    from c3_matcher_tools.run import open_matcher

    with (
        pytest.raises(UnknownStrategyError, match="no_such_strategy"),
        open_matcher(C3Settings(), "no_such_strategy", tmp_path),
    ):
        pass
    JsonlFdrRecorder(tmp_path / "fdr.jsonl", MonotonicClock()).close()  # the path is free
    with open_matcher(C3Settings(), "sift_magsac", tmp_path) as matcher:
        assert matcher.health_snapshot() is not None
    assert "c3.matcher.ready" in (tmp_path / "matcher.log").read_text()  # the run that composed


def test_open_matcher_refused_by_another_runs_lock_leaves_that_runs_fdr_and_log(
    tmp_path: Path,
) -> None:
    from c3_matcher.fdr import FdrOpenError, JsonlFdrRecorder, read_fdr
    from c3_matcher.health import MonotonicClock
    from c3_matcher_tools.run import open_matcher

    (tmp_path / "matcher.log").write_text("the running run's log\n")
    (tmp_path / "results.jsonl").write_text("the running run's results\n")
    running = JsonlFdrRecorder(tmp_path / "fdr.jsonl", MonotonicClock())
    try:
        running.record("matcher.frame_done", {"frame": 0})
        with (
            pytest.raises(FdrOpenError, match="another process"),
            open_matcher(C3Settings(), "sift_magsac", tmp_path),
        ):
            pass
        assert [r["seq"] for r in read_fdr(tmp_path / "fdr.jsonl")] == [1]
        assert (tmp_path / "matcher.log").read_text() == "the running run's log\n"
        assert (tmp_path / "results.jsonl").read_text() == "the running run's results\n"
    finally:
        running.close()


def test_open_matcher_refuses_an_unknown_strategy_before_touching_any_file(
    tmp_path: Path,
) -> None:
    from c3_matcher_tools.run import open_matcher

    previous = tmp_path / "previous"
    previous.mkdir()
    for name in ("fdr.jsonl", "matcher.log"):
        (previous / name).write_text(f"the previous run's {name}\n")
    for out in (previous, tmp_path / "new"):
        with (
            pytest.raises(UnknownStrategyError, match="no_such_strategy"),
            open_matcher(C3Settings(), "no_such_strategy", out),
        ):
            pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["previous"]
    assert sorted(p.name for p in previous.iterdir()) == ["fdr.jsonl", "matcher.log"]
    assert (previous / "fdr.jsonl").read_text() == "the previous run's fdr.jsonl\n"


def test_open_matcher_starts_the_fdr_afresh_and_forgets_the_previous_results(
    tmp_path: Path,
) -> None:
    from c3_matcher.fdr import JsonlFdrRecorder, read_fdr
    from c3_matcher.health import MonotonicClock
    from c3_matcher_tools.run import open_matcher

    previous = JsonlFdrRecorder(tmp_path / "fdr.jsonl", MonotonicClock(), max_bytes=1024)
    for i in range(40):
        previous.record("k", {"i": i, "pad": "x" * 40})
    assert len(previous.segments()) > 2
    previous.close()
    previous_results = ("results.jsonl", "report.json", "flight.geojson", "report.html")
    for name in (*previous_results, "notes.txt"):
        (tmp_path / name).write_text("the previous run's\n")
    settings = C3Settings(fdr={"max_bytes": 1024})
    with open_matcher(settings, "sift_magsac", tmp_path) as matcher:
        assert matcher.health_snapshot() is not None
        # a run stopped from here on leaves its own FDR, never beside the previous results
        assert not any((tmp_path / name).exists() for name in previous_results)
    assert (tmp_path / "notes.txt").exists()  # what no run writes is the user's
    assert sorted(p.name for p in tmp_path.glob("fdr*")) == ["fdr.jsonl", "fdr.jsonl.lock"]
    assert list(read_fdr(tmp_path / "fdr.jsonl")) == []  # this run recorded no frame


def test_a_frame_without_its_true_tile_has_its_truth_through_the_distractors() -> None:
    """Every candidate's ground-truth homography maps the same ground plane: dropping the true
    tile (as a frame without it) leaves the principal point's truth where it was, not at the
    footprint polygon's centre."""
    from c3_matcher.georef import haversine_m
    from c3_matcher_tools.run import truth_position

    dataset = load_dataset(Path(__file__).resolve().parents[3] / "data/flights/naip_demo")
    checked = 0
    for frame in dataset.frames:
        truth = truth_position(dataset, frame)
        if not any(c.is_true for c in frame.candidates) or truth is None:
            continue
        others = tuple(c for c in frame.candidates if not c.is_true)
        blind = truth_position(dataset, dataclasses.replace(frame, candidates=others))
        assert blind is not None, frame.index
        (lat, lon), (blat, blon) = truth, blind
        assert haversine_m([lon, lat], [blon, blat])[0] < 1.0, frame.index
        checked += 1
    assert checked >= 20


def test_the_pytorch_reference_filters_as_the_engine_cases_do(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """bench's reference row runs the same per-frame loop with the same RANSAC: the
    strategy's refit threshold (DISK's 2 px) and its floor. It had no refit: its inlier column
    (1206 against the engine's 1173 on the demo frame) was not comparable."""
    from c3_matcher.compose import build_plugin_host
    from c3_matcher.fdr import InMemoryFdr
    from c3_matcher.testing import (
        FakeBackend,
        FakeClock,
        FakeInferenceRuntime,
        FakeLightGlueRuntime,
    )
    from c3_matcher_tools.run.matcher import _reference_matcher

    host = build_plugin_host()
    backend = FakeBackend(FakeInferenceRuntime(), FakeLightGlueRuntime())
    monkeypatch.setattr(host, "reference_backend", lambda strategy, settings: backend)
    settings = C3Settings()
    composed = _reference_matcher(settings, host, InMemoryFdr(), FakeClock())
    ransac = composed.matcher._verification.ransac  # type: ignore[attr-defined]
    defaults = host.resolve("disk_lightglue").defaults
    assert ransac.refit_px == defaults.refit_threshold_px == 2.0
    assert ransac.refit_floor == settings.matcher.min_inliers_threshold


def test_a_run_whose_log_cannot_be_written_flies_and_counts_the_lines_lost(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """matcher.log on a full disk: the frames are matched all the same, and the run says how
    many log lines were lost (replay prints it, report.json holds it)."""
    import io

    from c3_matcher_tools.run.matcher import _HeldBackLog

    class FullDisk(io.StringIO):
        def write(self, s: str) -> int:
            raise OSError(28, "No space left on device")

    attach = _HeldBackLog.attach
    monkeypatch.setattr(_HeldBackLog, "attach", lambda log, stream: attach(log, FullDisk()))
    flight = load_dataset(DEMO)
    flight = dataclasses.replace(flight, frames=flight.frames[:2])
    from c3_matcher.compose import build_plugin_host

    run = fly(
        C3Settings(), "sift_magsac", flight, tmp_path / "run", plugin_host=build_plugin_host()
    )
    assert [o.index for o in run.outcomes] == [0, 1]
    assert run.log_lines_lost > 0
