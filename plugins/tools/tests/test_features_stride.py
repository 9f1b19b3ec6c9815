"""Map features built at a stride coarser than a flight's own grid (``features build FLIGHT
--flight-candidates --stride 128``): a candidate whose window is off that grid is served the
nearest grid window's features, shifted into its own px, and only those that fall on its window
(the strip the nearest window does not cover has none), never extracted. XFeat in process, on
the first frame of a copy of the demo flight (its three candidates all off the 128 px grid)."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
FRAMES = 1  # frames kept in the copy: their candidates are the build's windows
STRIDE = 128  # px: every candidate of the first frame lies off this grid
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory, engine_dir: Path) -> Path:
    """A copy of the demo flight cut to its first frames, its map features built on the
    ``STRIDE`` grid for its candidates, as a user builds them."""
    from c3_matcher.cli import main

    copy = tmp_path_factory.mktemp("stride") / "naip_demo"
    shutil.copytree(FLIGHT, copy)
    lines = (FLIGHT / "frames.jsonl").read_text().splitlines(keepends=True)
    (copy / "frames.jsonl").write_text("".join(lines[:FRAMES]))
    mp = pytest.MonkeyPatch()
    mp.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    try:
        argv = ["features", "build", str(copy), "--strategy", "xfeat", "--workers", "0"]
        assert main([*argv, "--flight-candidates", "--stride", str(STRIDE)]) == 0
    finally:
        mp.undo()
    return copy


def _matcher(engine_dir: Path) -> tuple[Any, Any, Any, io.StringIO]:
    """A stored-features XFeat matcher, its FDR, its log handle and the WARNING log stream."""
    from c3_matcher.compose import build_default_helpers, compose_root
    from c3_matcher.config import load_settings
    from c3_matcher.fdr import InMemoryFdr
    from c3_matcher.logs import configure_logging

    s = load_settings(None, env={"C3_MATCHER_ENGINES__DIRECTORY": str(engine_dir)})
    update = {"strategy": "xfeat", "tile_cache_size": 0, "stored_features": True}
    s = s.model_copy(update={"matcher": s.matcher.model_copy(update=update)})
    fdr, stream = InMemoryFdr(), io.StringIO()
    handle = configure_logging(fdr, level="WARNING", stream=stream)
    root = compose_root(s, {**build_default_helpers(s), "c13_fdr": fdr}, configure_logs=False)
    return root.matcher, fdr, handle, stream


def _off_grid(dataset: Any) -> list[Any]:
    """Every candidate of the flight, each checked to lie off the ``STRIDE`` grid."""
    from c3_matcher.tilestore.handles import mosaic_origin

    candidates = [c for f in dataset.frames for c in f.candidates]
    origins = [mosaic_origin(c.tile_id, dataset.candidate_size_px) for c in candidates]
    assert len(candidates) == 3 * FRAMES and all(x % STRIDE or y % STRIDE for x, y in origins)
    return candidates


def test_candidates_off_the_grid_are_matched_on_stored_features(
    flight: Path, engine_dir: Path
) -> None:
    """Every candidate is served from the store (the FDR says ``stored``), none refused."""
    from c3_matcher.errors import InsufficientInliersError
    from c3_matcher_tools.dataset.format import load_dataset

    dataset = load_dataset(flight)
    _off_grid(dataset)
    matcher, fdr, handle, stream = _matcher(engine_dir)
    try:
        with dataset.open_store() as store:
            for f in dataset.frames:
                with contextlib.suppress(InsufficientInliersError):  # its sources still said
                    matcher.match(
                        dataset.nav_frame(f), dataset.rerank(f, store), dataset.calibration
                    )
    finally:
        handle.close()
    logged = [json.loads(line) for line in stream.getvalue().splitlines() if line]
    assert [r["message"] for r in logged if "stored_features" in r["kind"]] == []
    done = fdr.of_kind("matcher.frame_done") + fdr.of_kind("matcher.insufficient_inliers")
    assert [d["candidate_features"] for d in done] == [["stored"] * 3] * FRAMES


def test_an_off_grid_candidate_gets_the_nearest_window_shifted_onto_its_own(
    flight: Path, engine_dir: Path
) -> None:
    """The nearest grid window's keypoints moved by the offset between the two windows, those
    on the candidate's window kept in their order (best first), with their own descriptors."""
    from c3_matcher.preprocess import FramePreprocessor
    from c3_matcher.stages.candidate_features import feature_request
    from c3_matcher.tilestore.features import grid_index
    from c3_matcher.tilestore.handles import mosaic_origin
    from c3_matcher_tools.dataset.format import load_dataset

    dataset = load_dataset(flight)
    size = dataset.candidate_size_px
    matcher, _, handle, _ = _matcher(engine_dir)
    handle.close()
    backend = matcher.backend
    pre = FramePreprocessor(backend.input_rule, photometric=matcher.settings.photometric)
    request = feature_request(backend, pre)
    assert request is not None
    with dataset.open_store() as store:
        sidecar = store.feature_store()
        assert sidecar is not None
        fset = sidecar.feature_set(request.set_id(size))
        assert fset is not None and fset.stride_px == STRIDE
        for c in _off_grid(dataset):
            origin = mosaic_origin(c.tile_id, size)
            gx, gy = grid_index(origin, STRIDE)
            nearest = sidecar.window(fset, c.tile_id.zoom, gx, gy)
            served = store.handle(c.tile_id, size).stored_features(request)
            assert nearest is not None and served is not None
            shift = np.array([gx * STRIDE - origin[0], gy * STRIDE - origin[1]], np.float32)
            moved = nearest.keypoints + shift
            on = ((moved >= -0.5) & (moved <= size - 0.5)).all(axis=1)
            n = min(int(request.max_keypoints), int(on.sum()))
            assert n > 0 and not on.all() and served.image_size == (size, size)
            assert np.array_equal(served.keypoints, moved[on][:n])
            assert np.array_equal(served.descriptors, nearest.descriptors[on][:n])
            assert np.array_equal(served.keypoint_scores, nearest.scores[on][:n])
