"""Precompute a tile store's map features for one or more strategies, on Dask.

Each task extracts a batch of tiles in a worker process: for tile (z, x, y) the
``256 + 2 * margin`` px square centred on it is stitched from the store (missing neighbours are
nodata, masked), prepared exactly as the flight prepares a tile (``FramePreprocessor
.prepare_tile``: same valid mask and erosion), run through the strategy's own
``FeatureBackend.extract`` (the engine the flight loads) with a keypoint budget of the engine's
full top-K, and only the keypoints in the tile's 256 px core are kept, in tile px. The client
is the single writer of the sidecar (``<store>.features.sqlite``): idempotent and resumable,
tiles already stored for the same set with the same bytes digest are skipped.

Cluster: ``dask.distributed.LocalCluster(n_workers=workers, threads_per_worker=1)`` by default,
or ``Client(scheduler)`` for an existing cluster (its workers need this environment and read
access to the store path). Without Dask installed, ``workers=0`` runs in this process.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.config import C3Settings
from c3_matcher.tilestore.features import (
    FeatureSet,
    TileFeatures,
    TileFeatureStore,
    set_id_for,
    sidecar_path,
    tile_digest,
)
from c3_matcher.tilestore.geo import TILE_PX

__all__ = ["BuildReport", "build_features", "extract_tile_features"]

DEFAULT_MARGIN_PX = 64
EXTRACT_BUDGET = 8192  # keep the engine's whole top-K per tile (capped by the graph's K)

TileKey = tuple[int, int, int]


@dataclass
class BuildReport:
    store: str
    sidecar: str
    strategies: dict[str, dict[str, Any]] = field(default_factory=dict)


_BACKENDS: dict[tuple[str, str], Any] = {}


def _backend(strategy: str, settings_json: str) -> Any:
    """The strategy's FeatureBackend, built once per worker process."""
    key = (strategy, settings_json)
    if key not in _BACKENDS:
        from loguru import logger

        from c3_matcher.compose import build_default_helpers, compose_root
        from c3_matcher.fdr import InMemoryFdr

        logger.remove()
        settings = C3Settings.model_validate_json(settings_json)
        m = settings.matcher.model_copy(
            update={"strategy": strategy, "max_keypoints": EXTRACT_BUDGET, "tile_cache_size": 0}
        )
        chosen = settings.model_copy(update={"matcher": m})
        helpers = build_default_helpers(chosen)
        root = compose_root(chosen, {**helpers, "c13_fdr": InMemoryFdr()}, configure_logs=False)
        _BACKENDS[key] = root.matcher.backend  # type: ignore[attr-defined]
    return _BACKENDS[key]


def _backend_facts(backend: Any) -> tuple[str, int]:
    sha = backend.provenance()["engines"]["extractor"]["file_sha256"]
    return str(sha), int(backend.input_rule.multiple)


def extract_tile_features(
    backend: Any,
    source: Any,
    zoom: int,
    x: int,
    y: int,
    margin_px: int,
    descriptor_dtype: str = "float32",
    photometric: str = "none",
) -> TileFeatures | None:
    """One tile's features (tile px) extracted with ``margin_px`` of context, through the
    flight's ``photometric`` normalisation; None when the store has no such tile."""
    from c3_matcher.preprocess import FramePreprocessor
    from c3_matcher.tilestore.handles import stitch

    blob = source.tile_bytes(zoom, x, y)
    if blob is None:
        return None
    size = TILE_PX + 2 * margin_px
    image = stitch(
        source, zoom, (x * TILE_PX - margin_px, y * TILE_PX - margin_px), (size, size), "tile"
    )
    prepared = FramePreprocessor(backend.input_rule, photometric=photometric).prepare_tile(image)
    if prepared.working_size != prepared.engine_size:
        raise ValueError(f"input rule {backend.input_rule} resizes a {size} px tile context")
    features = backend.extract(prepared)
    kp = features.keypoints - np.float32(margin_px)
    r = np.rint(kp)
    keep = (r[:, 0] >= 0) & (r[:, 0] < TILE_PX) & (r[:, 1] >= 0) & (r[:, 1] < TILE_PX)
    dtype = np.float16 if descriptor_dtype == "float16" else np.float32
    return TileFeatures(
        tile_digest(blob),
        np.ascontiguousarray(kp[keep], dtype=np.float32),
        np.ascontiguousarray(features.keypoint_scores[keep], dtype=np.float32),
        np.ascontiguousarray(features.descriptors[keep].astype(dtype)),
    )


def _open_source(store_path: str) -> Any:
    from c3_matcher.tilestore.mbtiles import MBTilesStore

    return MBTilesStore(store_path)


def _task(
    store_path: str,
    strategy: str,
    settings_json: str,
    margin_px: int,
    descriptor_dtype: str,
    tiles: Sequence[TileKey],
) -> tuple[list[tuple[int, int, int, TileFeatures]], float]:
    """A worker's batch: [(z, x, y, features)] and the seconds it took."""
    started = time.perf_counter()
    backend = _backend(strategy, settings_json)
    source = _open_source(store_path)
    try:
        out = []
        photometric = C3Settings.model_validate_json(settings_json).matcher.photometric
        for z, x, y in tiles:
            t = extract_tile_features(
                backend, source, z, x, y, margin_px, descriptor_dtype, photometric
            )
            if t is not None:
                out.append((z, x, y, t))
    finally:
        source.close()
    return out, time.perf_counter() - started


def _set_facts(strategy: str, settings_json: str) -> tuple[str, int, int]:
    """(extractor sha256, size multiple, descriptor dim) of a strategy, in a worker."""
    backend = _backend(strategy, settings_json)
    sha, multiple = _backend_facts(backend)
    from c3_matcher.preprocess import PreparedImage

    probe = np.kron(
        np.random.default_rng(0).integers(0, 256, (22, 22, 3), dtype=np.uint8),
        np.ones((6, 6, 1), np.uint8),
    )[:128, :128]
    f = backend.extract(
        PreparedImage(np.ascontiguousarray(probe), np.ones((128, 128), bool), np.eye(3), (128, 128))
    )
    return sha, multiple, int(f.descriptors.shape[1])


def _batches(items: list[TileKey], size: int) -> Iterator[list[TileKey]]:
    for i in range(0, len(items), size):
        yield items[i : i + size]


def build_features(
    store: Path,
    strategies: Sequence[str],
    settings: C3Settings,
    *,
    workers: int = 2,
    scheduler: str | None = None,
    margin_px: int = DEFAULT_MARGIN_PX,
    descriptor_dtype: str = "float32",
    batch_size: int = 8,
    progress: Callable[[str], None] | None = None,
) -> BuildReport:
    """Precompute ``store``'s map features for each strategy (see the module docstring)."""
    say = progress or (lambda line: print(line, file=sys.stderr, flush=True))
    if margin_px < 0 or (2 * margin_px) % 32:
        raise ValueError(f"margin_px must be >= 0 with 2 * margin a multiple of 32: {margin_px}")
    store = Path(store)
    settings_json = settings.model_dump_json()
    with _open_source(str(store)) as source:
        all_tiles: list[TileKey] = [(z, x, y) for z in source.zooms() for x, y in source.tiles(z)]
        digests = {k: tile_digest(source.tile_bytes(*k) or b"") for k in all_tiles}
    report = BuildReport(str(store), str(sidecar_path(store)))
    client: Any = None
    cluster: Any = None
    if workers > 0 or scheduler:
        from dask.distributed import Client, LocalCluster

        if scheduler:
            client = Client(scheduler)
        else:
            cluster = LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
            )
            client = Client(cluster)
    try:
        with TileFeatureStore(sidecar_path(store), writable=True) as sidecar:
            for strategy in strategies:
                if client is not None:
                    sha, multiple, dim = client.submit(
                        _set_facts, strategy, settings_json, pure=False
                    ).result()
                else:
                    sha, multiple, dim = _set_facts(strategy, settings_json)
                set_id = set_id_for(sha, multiple, settings.matcher.photometric)
                fset = FeatureSet(
                    set_id, sha, multiple, margin_px, dim, descriptor_dtype, strategy, False, 0
                )
                existing = sidecar.feature_set(set_id)
                if existing is not None and (
                    existing.margin_px != margin_px or existing.descriptor_dtype != descriptor_dtype
                ):
                    raise ValueError(
                        f"{sidecar.path}: set {set_id} was built with margin "
                        f"{existing.margin_px} px, {existing.descriptor_dtype}; remove it first"
                    )
                sidecar.ensure_set(fset)
                done = sidecar.done_tiles(set_id)
                todo = [k for k in all_tiles if done.get(k) != digests[k]]
                skipped = len(all_tiles) - len(todo)
                say(
                    f"features {strategy}: {len(all_tiles)} tiles, {skipped} already done, "
                    f"{len(todo)} to extract ({set_id[:12]}..., margin {margin_px} px)"
                )
                started = time.perf_counter()
                busy_s = 0.0
                written = 0
                args = (str(store.resolve()), strategy, settings_json, margin_px, descriptor_dtype)
                batches = list(_batches(todo, batch_size))
                if client is not None:
                    from dask.distributed import as_completed

                    futures = [client.submit(_task, *args, b, pure=False) for b in batches]
                    results: Iterator[Any] = (f.result() for f in as_completed(futures))
                else:
                    results = (_task(*args, b) for b in batches)
                for rows, seconds in results:
                    sidecar.put_tiles(set_id, rows)
                    busy_s += seconds
                    written += len(rows)
                    elapsed = time.perf_counter() - started
                    say(
                        f"features {strategy}: {written}/{len(todo)} tiles, "
                        f"{written / max(elapsed, 1e-9):.2f} tiles/s"
                    )
                elapsed = time.perf_counter() - started
                cores = _cores(client, workers)
                sidecar.mark(set_id, complete=True, tiles=len(sidecar.done_tiles(set_id)))
                report.strategies[strategy] = {
                    "set_id": set_id,
                    "tiles": len(all_tiles),
                    "skipped": skipped,
                    "extracted": written,
                    "seconds": elapsed,
                    "worker_seconds": busy_s,
                    "cores": cores,
                    "tiles_per_s": written / elapsed if elapsed > 0 else 0.0,
                    "tiles_per_s_per_core": (written / elapsed / cores) if elapsed > 0 else 0.0,
                }
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
    return report


def _cores(client: Any, workers: int) -> int:
    if client is None:
        return 1
    try:
        info = client.scheduler_info()["workers"]
        return max(1, sum(int(w.get("nthreads", 1)) for w in info.values()))
    except Exception:
        return max(1, workers or (os.cpu_count() or 1))
