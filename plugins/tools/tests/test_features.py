"""Map features computed once on the ground, on the real path (XFeat, the fastest engine, over
a copy of the demo flight): ``features build FLIGHT --flight-candidates`` (in process, then
resumed on a 2-worker Dask cluster with nothing left to do), stored features equal to extracting
the candidate's window bit for bit, the same match results and FDR sources, and the faults: a
sidecar locked by another process and a row altered into finite garbage cost no frame time and
no result, and are said once (log and FDR)."""

from __future__ import annotations

import io
import json
import shutil
import sqlite3
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
FRAMES = 4  # frames matched per check
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory, engine_dir: Path) -> Path:
    from c3_matcher.cli import main
    from c3_matcher.config import load_settings
    from c3_matcher_tools.features.build import build_features, flight_windows

    flight = tmp_path_factory.mktemp("flight") / "naip_demo"
    shutil.copytree(FLIGHT, flight)
    mp = pytest.MonkeyPatch()
    mp.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    try:
        argv = ["features", "build", str(flight), "--strategy", "xfeat", "--workers", "0"]
        assert main([*argv, "--flight-candidates", "--json"]) == 0
        windows = flight_windows(flight, 32)
        lines: list[str] = []
        again = build_features(
            flight / "tiles.mbtiles",
            ["xfeat"],
            load_settings(None),
            window_px=448,
            stride_px=32,
            windows=windows,
            workers=2,
            progress=lines.append,
        )
    finally:
        mp.undo()
    r = again.strategies["xfeat"]
    assert r["windows"] == len(windows) > 0 and r["cores"] == 2
    assert r["extracted"] == 0 and r["skipped"] == len(windows)  # resumable: all done
    assert any("already done" in line for line in lines)
    return flight


def _matcher(engine_dir: Path, stored: bool, fdr: Any = None):  # type: ignore[no-untyped-def]
    from c3_matcher.compose import build_default_helpers, compose_root
    from c3_matcher.config import load_settings
    from c3_matcher.fdr import InMemoryFdr

    s = load_settings(None, env={"C3_MATCHER_ENGINES__DIRECTORY": str(engine_dir)})
    update = {"strategy": "xfeat", "tile_cache_size": 0, "stored_features": stored}
    s = s.model_copy(update={"matcher": s.matcher.model_copy(update=update)})
    fdr = fdr if fdr is not None else InMemoryFdr()
    root = compose_root(s, {**build_default_helpers(s), "c13_fdr": fdr}, configure_logs=False)
    return root.matcher, fdr


def _run(matcher: Any, dataset: Any, store: Any) -> list[tuple[Any, float]]:
    """(result or the InsufficientInliersError, seconds) of the first FRAMES frames."""
    from c3_matcher.errors import InsufficientInliersError

    out: list[tuple[Any, float]] = []
    for f in dataset.frames[:FRAMES]:
        frame, rerank = dataset.nav_frame(f), dataset.rerank(f, store)
        started = time.perf_counter()
        try:
            result: Any = matcher.match(frame, rerank, dataset.calibration)
        except InsufficientInliersError as exc:
            result = exc
        out.append((result, time.perf_counter() - started))
    return out


def _same(a: Any, b: Any) -> bool:
    """Same picks, counts, residuals and inlier correspondences (bit for bit)."""
    if type(a) is not type(b):
        return False
    if not hasattr(a, "per_candidate"):
        return bool(a.best_inlier_count == b.best_inlier_count)
    return a.best_candidate_idx == b.best_candidate_idx and all(
        x.tile_id == y.tile_id
        and x.inlier_count == y.inlier_count
        and x.per_candidate_residual_px == y.per_candidate_residual_px
        and np.array_equal(x.inlier_correspondences, y.inlier_correspondences)
        for x, y in zip(a.per_candidate, b.per_candidate, strict=True)
    )


def _sources(fdr: Any) -> list[list[str]]:
    done = fdr.of_kind("matcher.frame_done") + fdr.of_kind("matcher.insufficient_inliers")
    return [d["candidate_features"] for d in done]


def test_stored_features_are_the_extracted_window_bit_for_bit(built: Path, engine_dir: Path):
    from c3_matcher.preprocess import FramePreprocessor
    from c3_matcher.stages.candidate_features import feature_request
    from c3_matcher_tools.dataset.format import load_dataset

    dataset = load_dataset(built)
    store = dataset.open_store()
    matcher, _ = _matcher(engine_dir, True)
    backend = matcher.backend
    pre = FramePreprocessor(backend.input_rule, photometric=matcher.settings.photometric)
    request = feature_request(backend, pre)
    assert request is not None and request.photometric == matcher.settings.photometric
    checked = 0
    for f in dataset.frames[:FRAMES]:
        for candidate in dataset.rerank(f, store).candidates:
            handle = candidate.tile_pixels_handle
            stored = handle.stored_features(request)
            extracted = backend.extract(pre.prepare_tile(handle.decode()))
            assert stored is not None and stored.image_size == extracted.image_size
            for name in ("keypoints", "descriptors", "keypoint_scores"):
                assert np.array_equal(getattr(stored, name), getattr(extracted, name)), name
            checked += 1
    assert checked == 3 * FRAMES
    store.close()


def test_matching_stored_features_gives_the_results_of_extraction(built: Path, engine_dir: Path):
    from c3_matcher_tools.dataset.format import load_dataset

    dataset = load_dataset(built)
    store = dataset.open_store()
    stored_m, stored_fdr = _matcher(engine_dir, True)
    extract_m, extract_fdr = _matcher(engine_dir, False)
    stored = _run(stored_m, dataset, store)
    extracted = _run(extract_m, dataset, store)
    assert all(_same(a, b) for (a, _), (b, _) in zip(stored, extracted, strict=True))
    assert _sources(stored_fdr) == [["stored"] * 3] * FRAMES
    assert _sources(extract_fdr) == [["extracted"] * 3] * FRAMES
    store.close()


def _logged(engine_dir: Path) -> tuple[Any, Any, Any, io.StringIO]:
    """A stored-features matcher whose WARNING logs go to a stream and to its FDR."""
    from c3_matcher.fdr import InMemoryFdr
    from c3_matcher.logs import configure_logging

    fdr = InMemoryFdr()
    stream = io.StringIO()
    handle = configure_logging(fdr, level="WARNING", stream=stream)
    matcher, _ = _matcher(engine_dir, True, fdr)
    return matcher, fdr, handle, stream


def _warnings(stream: io.StringIO) -> list[dict[str, Any]]:
    records = [json.loads(line) for line in stream.getvalue().splitlines() if line]
    return [r for r in records if r["kind"] == "c3.matcher.stored_features_failed"]


def test_a_sidecar_locked_by_another_process_costs_no_frame_time(built: Path, engine_dir: Path):
    from c3_matcher.testing.locks import exclusive_lock
    from c3_matcher.tilestore.features import sidecar_path
    from c3_matcher_tools.dataset.format import load_dataset

    dataset = load_dataset(built)
    reference, _ = _matcher(engine_dir, False)
    with dataset.open_store() as store:
        expected = _run(reference, dataset, store)
    matcher, fdr, handle, stream = _logged(engine_dir)
    try:
        with exclusive_lock(sidecar_path(dataset.store_path)), dataset.open_store() as store:
            got = _run(matcher, dataset, store)
    finally:
        handle.close()
    assert all(_same(a, b) for (a, _), (b, _) in zip(got, expected, strict=True))
    # SQLite's default busy timeout waited 5 s per candidate (15 s a frame): now none
    assert max(seconds for _, seconds in got) < 4.5, [s for _, s in got]
    assert _sources(fdr) == [["extracted"] * 3] * FRAMES
    (warning,) = _warnings(stream)  # said once, not per candidate or frame
    assert "locked" in warning["message"] and "extracting instead" in warning["message"]
    forwarded = [r for r in fdr.of_kind("log.warning") if "locked" in r.get("message", "")]
    assert len(forwarded) == 1


def test_a_row_of_finite_garbage_is_refused_and_extracted(built: Path, engine_dir: Path):
    from c3_matcher.tilestore.features import sidecar_path
    from c3_matcher.tilestore.handles import mosaic_origin
    from c3_matcher_tools.dataset.format import load_dataset

    dataset = load_dataset(built)
    frame = dataset.frames[0]
    gx, gy = (v // 32 for v in mosaic_origin(frame.candidates[0].tile_id, 448))
    copy = built.parent / "garbage"
    shutil.copytree(built, copy)
    with sqlite3.connect(sidecar_path(copy / "tiles.mbtiles")) as db:
        n, dim = db.execute(
            "SELECT n, descriptor_dim FROM window_features JOIN window_sets USING (set_id) "
            "WHERE gx=? AND gy=?",
            (gx, gy),
        ).fetchone()
        garbage = np.random.default_rng(0).uniform(-0.2, 0.2, (n, dim)).astype(np.float32)
        db.execute(
            "UPDATE window_features SET descriptors=? WHERE gx=? AND gy=?",
            (garbage.tobytes(), gx, gy),
        )
    garbled = load_dataset(copy)
    reference, _ = _matcher(engine_dir, False)
    with garbled.open_store() as store:
        expected = _run(reference, garbled, store)
    matcher, fdr, handle, stream = _logged(engine_dir)
    try:
        with garbled.open_store() as store:
            got = _run(matcher, garbled, store)
    finally:
        handle.close()
    assert all(_same(a, b) for (a, _), (b, _) in zip(got, expected, strict=True))
    assert _sources(fdr)[0] == ["extracted", "stored", "stored"]
    (warning,) = _warnings(stream)
    assert "checksum mismatch; refused" in warning["message"]


def test_info_counts_the_windows_a_stopped_build_left(
    built: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A set a stopped build left incomplete shows the windows it holds (it showed 0)."""
    from c3_matcher.cli import main
    from c3_matcher.tilestore.features import MapFeatureStore, sidecar_path

    store = tmp_path / "tiles.mbtiles"
    shutil.copy(built / "tiles.mbtiles", store)
    shutil.copy(sidecar_path(built / "tiles.mbtiles"), sidecar_path(store))
    with MapFeatureStore(sidecar_path(store), writable=True) as side:
        (fset,) = side.feature_sets()
        stored = len(side.done_windows(fset.set_id))
        side.mark(fset.set_id, complete=False, windows=0)  # as a build stopped at its start
    assert main(["features", "info", str(store), "--json"]) == 0
    (shown,) = json.loads(capsys.readouterr().out)["sets"]
    assert shown["complete"] is False and shown["windows"] == stored > 0
