"""Why features assembled from separately extracted tiles match worse than the window's own.

    .venv/bin/python scripts/stored_features_gap.py FLIGHT_DIR [N_FRAMES] [STRATEGY]

For the true candidate of the first ``N_FRAMES`` (default 12) frames whose true tile is present,
with the configured ``[matcher]`` settings (photometric normalisation included), it builds the
candidate window's features five ways and matches each against the frame through the full
pipeline (that candidate alone):

- ``extracted``: the window itself, as the flight extracts it (what stored features now are);
- ``tiles_m64`` / ``tiles_m192``: the former read path, every covered tile extracted with a
  64 / 192 px context margin, the keypoints of each tile's core shifted into the window and the
  best ``max_keypoints`` kept by score;
- ``window_plus_64``: the window extracted with 64 px more context on every side, cropped back;
- ``common_window_desc`` / ``common_tiles_desc``: only the keypoints ``extracted`` and
  ``tiles_m64`` share (same rounded px), with the window's descriptors / the tiles' descriptors:
  what the keypoint set costs, and what the descriptors cost.

Printed per variant (median over the frames): best inliers, the share of the window's keypoints
also found (same rounded px) and the median descriptor cosine at those shared keypoints.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.compose import build_default_helpers, compose_root
from c3_matcher.config import load_settings
from c3_matcher.dto import RerankCandidate, RerankResult
from c3_matcher.errors import InsufficientInliersError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.features import Features
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.tilestore.geo import TILE_PX
from c3_matcher.tilestore.handles import mosaic_origin, stitch
from c3_matcher_tools.dataset.format import load_dataset


class _Handle:
    """A candidate handle serving fixed pixels and fixed "stored" features."""

    def __init__(self, pixels: Any, features: Features) -> None:
        self._pixels, self._features = pixels, features

    def decode(self) -> Any:
        return self._pixels.copy()

    def encoded(self) -> memoryview:
        raise NotImplementedError

    def stored_features(self, request: Any) -> Features:
        return self._features


def _inside(kp: Any, size: int, erode: int) -> Any:
    r = np.rint(kp)
    return (
        (r[:, 0] >= erode)
        & (r[:, 0] <= size - 1 - erode)
        & (r[:, 1] >= erode)
        & (r[:, 1] <= size - 1 - erode)
    )


def _subset(f: Features, idx: Any) -> Features:
    return Features(
        np.ascontiguousarray(f.keypoints[idx]),
        np.ascontiguousarray(f.descriptors[idx]),
        np.ascontiguousarray(f.keypoint_scores[idx]),
        f.image_size,
    )


def _from_tiles(
    backend: Any, pre: Any, store: Any, zoom: int, origin: Any, size: int, margin: int, budget: int
) -> Features:
    """The former read path: per-tile extraction with ``margin`` px of context, assembled."""
    x0, y0 = origin
    kps, scs, dss = [], [], []
    for ty in range(y0 // TILE_PX, (y0 + size - 1) // TILE_PX + 1):
        for tx in range(x0 // TILE_PX, (x0 + size - 1) // TILE_PX + 1):
            if store.tile_bytes(zoom, tx, ty) is None:
                continue
            ctx = TILE_PX + 2 * margin
            image = stitch(
                store, zoom, (tx * TILE_PX - margin, ty * TILE_PX - margin), (ctx, ctx), "t"
            )
            f = backend.extract(pre.prepare_tile(image))
            kp = f.keypoints - np.float32(margin)
            r = np.rint(kp)
            core = (r[:, 0] >= 0) & (r[:, 0] < TILE_PX) & (r[:, 1] >= 0) & (r[:, 1] < TILE_PX)
            kp = kp[core] + np.array([tx * TILE_PX - x0, ty * TILE_PX - y0], np.float32)
            keep = _inside(kp, size, pre.border_erode_px)
            kps.append(kp[keep])
            scs.append(f.keypoint_scores[core][keep])
            dss.append(f.descriptors[core][keep])
    kp, sc, de = np.concatenate(kps), np.concatenate(scs), np.concatenate(dss)
    order = np.argsort(-sc, kind="stable")[:budget]
    return Features(
        np.ascontiguousarray(kp[order]),
        np.ascontiguousarray(de[order]),
        np.ascontiguousarray(sc[order]),
        (size, size),
    )


def _with_context(
    backend: Any, pre: Any, store: Any, zoom: int, origin: Any, size: int, margin: int
) -> Features:
    big = stitch(
        store, zoom, (origin[0] - margin, origin[1] - margin), (size + 2 * margin,) * 2, "w"
    )
    f = backend.extract(pre.prepare_tile(big))
    shifted = Features(
        f.keypoints - np.float32(margin), f.descriptors, f.keypoint_scores, (size, size)
    )
    return _subset(shifted, np.flatnonzero(_inside(shifted.keypoints, size, pre.border_erode_px)))


def _agreement(f: Features, window: Features) -> tuple[float, float]:
    at = {tuple(p): i for i, p in enumerate(np.rint(f.keypoints).astype(int).tolist())}
    pairs = [
        (at[tuple(p)], i)
        for i, p in enumerate(np.rint(window.keypoints).astype(int).tolist())
        if tuple(p) in at
    ]
    cos = [float(f.descriptors[a] @ window.descriptors[b]) for a, b in pairs]
    return len(pairs) / max(1, len(window.keypoints)), float(np.median(cos)) if cos else float(
        "nan"
    )


def main(argv: list[str]) -> int:
    flight, n = Path(argv[0]), int(argv[1]) if len(argv) > 1 else 12
    strategy = argv[2] if len(argv) > 2 else "xfeat"
    settings = load_settings(None)
    m = settings.matcher.model_copy(update={"strategy": strategy, "tile_cache_size": 0})
    settings = settings.model_copy(update={"matcher": m})
    helpers = {**build_default_helpers(settings), "c13_fdr": InMemoryFdr()}
    matcher: Any = compose_root(settings, helpers, configure_logs=False).matcher
    backend = matcher.backend
    pre = FramePreprocessor(backend.input_rule, photometric=matcher.settings.photometric)
    budget = int(backend.max_keypoints)
    dataset = load_dataset(flight)
    store = dataset.open_store()
    size = dataset.candidate_size_px
    rows = []
    for record in [f for f in dataset.frames if f.true_tile_present][:n]:
        frame, rerank = dataset.nav_frame(record), dataset.rerank(record, store)
        true = next(
            c for c, t in zip(rerank.candidates, record.candidates, strict=True) if t.is_true
        )
        origin, zoom = mosaic_origin(true.tile_id, size), true.tile_id.zoom
        pixels = true.tile_pixels_handle.decode()
        window = backend.extract(pre.prepare_tile(pixels))
        tiles64 = _from_tiles(backend, pre, store, zoom, origin, size, 64, budget)
        at = {tuple(p): i for i, p in enumerate(np.rint(tiles64.keypoints).astype(int).tolist())}
        shared = [
            (i, at[tuple(p)])
            for i, p in enumerate(np.rint(window.keypoints).astype(int).tolist())
            if tuple(p) in at
        ]
        variants = {
            "extracted": window,
            "tiles_m64": tiles64,
            "tiles_m192": _from_tiles(backend, pre, store, zoom, origin, size, 192, budget),
            "window_plus_64": _with_context(backend, pre, store, zoom, origin, size, 64),
            "common_window_desc": _subset(window, np.array([i for i, _ in shared])),
            "common_tiles_desc": _subset(tiles64, np.array([j for _, j in shared])),
        }
        row: dict[str, Any] = {"frame": record.index}
        for name, feats in variants.items():
            candidate = RerankCandidate(
                true.tile_id, 1.0, _Handle(pixels, feats), true.gsd_m_per_px
            )
            try:
                result = matcher.match(
                    frame, RerankResult(frame.frame_id, (candidate,)), dataset.calibration
                )
                inliers = result.per_candidate[0].inlier_count
            except InsufficientInliersError as exc:
                inliers = int(getattr(exc, "best_inlier_count", 0))
            share, cos = _agreement(feats, window)
            row[name] = [inliers, round(share, 3), round(cos, 3)]
        rows.append(row)
        print(json.dumps(row), flush=True)
    print(f"{strategy}, photometric {matcher.settings.photometric}, {len(rows)} frames, medians:")
    for name in variants:
        a = np.array([r[name] for r in rows], dtype=float)
        print(
            f"  {name:20s} inliers {np.median(a[:, 0]):5.0f}   keypoints shared "
            f"{np.median(a[:, 1]):.3f}   descriptor cosine {np.nanmedian(a[:, 2]):.3f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
