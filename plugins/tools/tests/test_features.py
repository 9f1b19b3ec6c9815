"""Map features computed once on the ground: ``features build`` on a 2-worker local Dask
cluster (idempotent, resumable), the flight read path (assembly, staleness, FDR source) and the
agreement of assembled features with extracting the window (XFeat, the fastest engine)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory, engine_dir: Path) -> Path:
    from c3_matcher.config import load_settings
    from c3_matcher_tools.features.build import build_features

    flight = tmp_path_factory.mktemp("flight") / "naip_demo"
    shutil.copytree(FLIGHT, flight)
    settings = load_settings(None, env={"C3_MATCHER_ENGINES__DIRECTORY": str(engine_dir)})
    lines: list[str] = []
    report = build_features(
        flight / "tiles.mbtiles", ["xfeat"], settings, workers=2, progress=lines.append
    )
    r = report.strategies["xfeat"]
    assert r["extracted"] == r["tiles"] > 0 and r["cores"] == 2
    assert any("tiles/s" in line for line in lines)
    again = build_features(
        flight / "tiles.mbtiles", ["xfeat"], settings, workers=0, progress=lines.append
    )
    assert again.strategies["xfeat"]["extracted"] == 0  # resumable: done tiles skipped
    assert again.strategies["xfeat"]["skipped"] == r["tiles"]
    return flight


def _matcher(stored: bool, engine_dir: Path):  # type: ignore[no-untyped-def]
    from c3_matcher.compose import build_default_helpers, compose_root
    from c3_matcher.config import load_settings
    from c3_matcher.fdr import InMemoryFdr

    s = load_settings(None, env={"C3_MATCHER_ENGINES__DIRECTORY": str(engine_dir)})
    s = s.model_copy(
        update={"matcher": s.matcher.model_copy(update={"strategy": "xfeat", "tile_cache_size": 0})}
    )
    fdr = InMemoryFdr()
    root = compose_root(s, {**build_default_helpers(s), "c13_fdr": fdr}, configure_logs=False)
    root.matcher.stored_features = stored
    return root.matcher, fdr


def test_assembled_features_agree_with_extraction(built: Path, engine_dir: Path) -> None:
    from c3_matcher.errors import InsufficientInliersError
    from c3_matcher.pipeline import _feature_request
    from c3_matcher.preprocess import FramePreprocessor
    from c3_matcher_tools.dataset.format import load_dataset

    dataset = load_dataset(built)
    store = dataset.open_store()
    stored_m, fdr = _matcher(True, engine_dir)
    extract_m, _ = _matcher(False, engine_dir)
    backend = stored_m.backend
    pre = FramePreprocessor(backend.input_rule, photometric=stored_m.settings.photometric)
    request = _feature_request(backend, pre)
    assert request is not None and request.photometric == "clahe"  # the flight default
    assert request is not None
    overlaps, counts = [], []
    frames = [f for f in dataset.frames if f.true_tile_present][:3]
    for f in frames:
        rerank = dataset.rerank(f, store)
        handle = rerank.candidates[0].tile_pixels_handle
        assembled = handle.stored_features(request)
        assert assembled is not None
        extracted = backend.extract(pre.prepare_tile(handle.decode()))
        a = {tuple(p) for p in np.rint(assembled.keypoints).astype(int).tolist()}
        e = {tuple(p) for p in np.rint(extracted.keypoints).astype(int).tolist()}
        overlaps.append(len(a & e) / len(e))
        pair = []
        for m in (stored_m, extract_m):
            try:
                pair.append(m.match(dataset.nav_frame(f), rerank, dataset.calibration))
            except InsufficientInliersError:
                pair.append(None)
        counts.append(tuple(r.per_candidate[0].inlier_count if r else 0 for r in pair))
    done = fdr.of_kind("matcher.frame_done") + fdr.of_kind("matcher.insufficient_inliers")
    assert done and all(set(d["candidate_features"]) <= {"stored", "none"} for d in done)
    print("keypoint overlap", overlaps, "inliers (stored, extracted)", counts)
    # Measured (README "Map features"): XFeat normalises the whole image (InstanceNorm), so
    # stored features are close to, not equal to, the window's: overlap 0.65-0.88.
    assert min(overlaps) >= 0.5
    # a different engine build never gets these features
    stale = type(request)("0" * 64, request.multiple, request.max_long_side, 4096)
    assert rerank.candidates[0].tile_pixels_handle.stored_features(stale) is None
    # nor features extracted under another photometric normalisation
    raw = type(request)(request.extractor_sha256, request.multiple, request.max_long_side, 4096)
    assert rerank.candidates[0].tile_pixels_handle.stored_features(raw) is None
