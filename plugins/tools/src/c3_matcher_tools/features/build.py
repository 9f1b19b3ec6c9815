"""Precompute a tile store's map features for one or more strategies, on Dask.

The store holds candidate WINDOWS, not tiles (see :mod:`c3_matcher.tilestore.features` for why
and for the sidecar format): every ``window_px`` square window of WORLD px on a ``stride_px``
grid that stored tiles cover to at least ``min_coverage`` (or an explicit list of grid windows,
e.g. those a recorded flight's candidates use) is stitched from the store, prepared exactly as
the flight prepares a candidate (``FramePreprocessor.prepare_tile`` under the configured
``[matcher] photometric``) and run through the strategy's own ``FeatureBackend.extract`` (the
engine and provider the flight loads) with a budget of the engine's whole top-K. The client is
the single writer of the sidecar (``<store>.features.sqlite``): idempotent and resumable,
windows already stored for the same set with the same tiles are skipped.

Cluster: ``dask.distributed.LocalCluster(n_workers=workers, threads_per_worker=1)`` by default,
or ``Client(scheduler)`` for an existing cluster (its workers need this environment and read
access to the store path). ``workers=0`` runs in this process, without Dask.
"""

from __future__ import annotations

import math
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
    MapFeatureStore,
    WindowFeatures,
    covered_tiles,
    grid_index,
    set_id_for,
    sidecar_path,
    tile_digest,
    window_digest,
)
from c3_matcher.tilestore.geo import TILE_PX

__all__ = [
    "BuildReport",
    "build_features",
    "extract_window_features",
    "flight_grid",
    "flight_windows",
    "grid_windows",
]

DEFAULT_WINDOW_PX = TILE_PX  # the store's own tiles as the candidates
DEFAULT_MIN_COVERAGE = 0.5
EXTRACT_BUDGET = 8192  # keep the engine's whole top-K per window (capped by the graph's K)

WindowKey = tuple[int, int, int]  # (zoom, gx, gy)


@dataclass
class BuildReport:
    store: str
    sidecar: str
    strategies: dict[str, dict[str, Any]] = field(default_factory=dict)


@dataclass(frozen=True)
class _Facts:
    """What keys a strategy's set, learnt from its backend in a worker."""

    extractor_sha256: str
    provider: str
    multiple: int
    border_erode_px: int
    descriptor_dim: int
    descriptor_dtype: str


BackendCache = dict[tuple[str, str], Any]


def _backend(strategy: str, settings_json: str, cache: BackendCache | None = None) -> Any:
    """The strategy's FeatureBackend with the whole top-K and no tile cache, built once per
    process: held in ``cache`` (the caller's, when it runs the tasks itself) or by the Dask
    worker running the task."""
    cache = _worker_cache() if cache is None else cache
    key = (strategy, settings_json)
    if key not in cache:
        from loguru import logger

        from c3_matcher_tools.run.matcher import Overrides, open_backend

        logger.remove()
        cache[key] = open_backend(
            C3Settings.model_validate_json(settings_json),
            strategy,
            overrides=Overrides(max_keypoints=EXTRACT_BUDGET, tile_cache_size=0),
        )
    return cache[key]


def _worker_cache() -> BackendCache:
    """The backends held by the Dask worker this task runs on (one per worker process)."""
    from dask.distributed import get_worker

    cache: BackendCache = get_worker().extensions.setdefault("c3_feature_backends", {})
    return cache


def _photometric(strategy: str, settings_json: str) -> str:
    """The photometric normalisation ``strategy`` flies with: ``[matcher] photometric``, or when
    unset the strategy's own default (``c3_matcher.compose.strategy_settings``)."""
    from c3_matcher.compose import strategy_settings

    settings = strategy_settings(C3Settings.model_validate_json(settings_json), strategy)
    return str(settings.matcher.photometric)


def _preprocessor(backend: Any, photometric: str) -> Any:
    """The flight's tile preprocessing (``PipelineMatcher``'s default preprocessor)."""
    from c3_matcher.preprocess import FramePreprocessor

    return FramePreprocessor(backend.input_rule, photometric=photometric)


def extract_window_features(
    backend: Any,
    source: Any,
    zoom: int,
    origin: tuple[int, int],
    window_px: int,
    photometric: str,
) -> WindowFeatures:
    """The features of the ``window_px`` window of WORLD px whose top-left pixel is ``origin``,
    exactly as the flight extracts a candidate with that window (window px); ValueError when
    the input rule would resize or pad the window."""
    from c3_matcher.tilestore.handles import stitch

    keys = covered_tiles(zoom, origin, (window_px, window_px))
    blobs = {k: source.tile_bytes(*k) for k in keys}
    digest = window_digest(keys, lambda k: None if blobs[k] is None else tile_digest(blobs[k]))
    image = stitch(source, zoom, origin, (window_px, window_px), f"window {zoom}/{origin}")
    prepared = _preprocessor(backend, photometric).prepare_tile(image)
    if prepared.engine_size != (window_px, window_px):
        raise ValueError(f"input rule {backend.input_rule} resizes or pads a {window_px} px window")
    f = backend.extract(prepared)
    return WindowFeatures(
        digest,
        np.ascontiguousarray(f.keypoints, dtype=np.float32),
        np.ascontiguousarray(f.keypoint_scores, dtype=np.float32),
        np.ascontiguousarray(f.descriptors),  # the backend's dtype, never cast
    )


def _open_source(store_path: str) -> Any:
    from c3_matcher.tilestore.mbtiles import MBTilesStore

    return MBTilesStore(store_path)


def _task(
    store_path: str,
    strategy: str,
    settings_json: str,
    window_px: int,
    stride_px: int,
    windows: Sequence[WindowKey],
    cache: BackendCache | None = None,
) -> tuple[list[tuple[int, int, int, WindowFeatures]], float]:
    """A worker's batch: [(zoom, gx, gy, features)] and the seconds it took (a window no stored
    tile overlaps has no features and is left out)."""
    from c3_matcher.tilestore.handles import TileNotFoundError

    started = time.perf_counter()
    backend = _backend(strategy, settings_json, cache)
    photometric = _photometric(strategy, settings_json)
    source = _open_source(store_path)
    out: list[tuple[int, int, int, WindowFeatures]] = []
    try:
        for z, gx, gy in windows:
            origin = (gx * stride_px, gy * stride_px)
            try:
                f = extract_window_features(backend, source, z, origin, window_px, photometric)
            except TileNotFoundError:
                continue
            out.append((z, gx, gy, f))
    finally:
        source.close()
    return out, time.perf_counter() - started


def _set_facts(strategy: str, settings_json: str, cache: BackendCache | None = None) -> _Facts:
    """The facts keying a strategy's set, in a worker (the descriptor size from a probe)."""
    backend = _backend(strategy, settings_json, cache)
    from c3_matcher.preprocess import PreparedImage

    probe = np.kron(
        np.random.default_rng(0).integers(0, 256, (22, 22, 3), dtype=np.uint8),
        np.ones((6, 6, 1), np.uint8),
    )[:128, :128]
    f = backend.extract(
        PreparedImage(np.ascontiguousarray(probe), np.ones((128, 128), bool), np.eye(3), (128, 128))
    )
    provenance = backend.provenance()
    photometric = _photometric(strategy, settings_json)
    return _Facts(
        str(provenance["engines"]["extractor"]["file_sha256"]),
        str(provenance["provider"]),
        int(backend.input_rule.multiple),
        int(_preprocessor(backend, photometric).border_erode_px),
        int(f.descriptors.shape[1]),
        str(f.descriptors.dtype),
    )


def grid_windows(
    tiles: set[tuple[int, int, int]], window_px: int, stride_px: int, min_coverage: float
) -> list[WindowKey]:
    """Every (zoom, gx, gy) grid window whose area stored ``tiles`` (zoom, x, y) cover to at
    least ``min_coverage`` (0 < share <= 1), sorted."""
    out: list[WindowKey] = []
    for zoom in sorted({t[0] for t in tiles}):
        xs = [t[1] for t in tiles if t[0] == zoom]
        ys = [t[2] for t in tiles if t[0] == zoom]
        g0x, g0y = (
            (min(xs) * TILE_PX - window_px) // stride_px,
            (min(ys) * TILE_PX - window_px) // stride_px,
        )
        g1x, g1y = (max(xs) + 1) * TILE_PX // stride_px, (max(ys) + 1) * TILE_PX // stride_px
        for gy in range(g0y, g1y + 1):
            for gx in range(g0x, g1x + 1):
                x0, y0 = gx * stride_px, gy * stride_px
                covered = 0
                for z, tx, ty in covered_tiles(zoom, (x0, y0), (window_px, window_px)):
                    if (z, tx, ty) in tiles:
                        ax, ay = max(x0, tx * TILE_PX), max(y0, ty * TILE_PX)
                        bx = min(x0 + window_px, (tx + 1) * TILE_PX)
                        by = min(y0 + window_px, (ty + 1) * TILE_PX)
                        covered += max(0, bx - ax) * max(0, by - ay)
                if covered > 0 and covered >= min_coverage * window_px * window_px:
                    out.append((zoom, gx, gy))
    return out


def flight_grid(dataset_dir: Path) -> tuple[int, int]:
    """(window, stride) px for a recorded flight: its candidates' size, and the grid their
    windows lie on (the greatest common divisor of their top-left WORLD px, at least 16 and at
    most the window): a build on that grid holds every candidate's own window."""
    from c3_matcher.tilestore.handles import mosaic_origin
    from c3_matcher_tools.dataset.format import load_dataset

    dataset = load_dataset(dataset_dir)
    size = dataset.candidate_size_px
    grid = 0
    for f in dataset.frames:
        for c in f.candidates:
            x0, y0 = mosaic_origin(c.tile_id, size)
            grid = math.gcd(grid, x0, y0)
    return size, min(max(grid, 16), size) if grid else size


def flight_windows(dataset_dir: Path, stride_px: int) -> list[WindowKey]:
    """The grid windows a recorded flight's candidates are served from (their nearest grid
    window; the windows themselves when they lie on the grid), sorted."""
    from c3_matcher.tilestore.handles import mosaic_origin
    from c3_matcher_tools.dataset.format import load_dataset

    dataset = load_dataset(dataset_dir)
    size = dataset.candidate_size_px
    keys = {
        (c.tile_id.zoom, *grid_index(mosaic_origin(c.tile_id, size), stride_px))
        for f in dataset.frames
        for c in f.candidates
    }
    return sorted(keys)


def _batches(items: list[WindowKey], size: int) -> Iterator[list[WindowKey]]:
    for i in range(0, len(items), size):
        yield items[i : i + size]


def build_features(
    store: Path,
    strategies: Sequence[str],
    settings: C3Settings,
    *,
    window_px: int = DEFAULT_WINDOW_PX,
    stride_px: int | None = None,
    min_coverage: float = DEFAULT_MIN_COVERAGE,
    windows: Sequence[WindowKey] | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    batch_size: int = 8,
    progress: Callable[[str], None] | None = None,
) -> BuildReport:
    """Precompute ``store``'s map features for each strategy (see the module docstring):
    ``window_px`` windows on a ``stride_px`` grid (default: ``window_px``), every window the
    store covers to ``min_coverage``, or only ``windows`` (zoom, gx, gy) when given."""
    say = progress or (lambda line: print(line, file=sys.stderr, flush=True))
    stride = int(stride_px or window_px)
    if not 16 <= window_px <= 8192 or not 1 <= stride <= window_px:
        raise ValueError(
            f"window must be in [16, 8192] px and stride in [1, window]: {window_px}, {stride}"
        )
    if not 0.0 < min_coverage <= 1.0:
        raise ValueError(f"min_coverage must be in (0, 1], got {min_coverage}")
    store = Path(store)
    settings_json = settings.model_dump_json()
    with _open_source(str(store)) as source:
        tiles = {(z, x, y) for z in source.zooms() for x, y in source.tiles(z)}
        digests = {k: tile_digest(source.tile_bytes(*k) or b"") for k in tiles}
    todo_all = (
        sorted(set(windows))
        if windows is not None
        else grid_windows(tiles, window_px, stride, min_coverage)
    )
    wanted = {
        (z, gx, gy): window_digest(
            covered_tiles(z, (gx * stride, gy * stride), (window_px, window_px)), digests.get
        )
        for z, gx, gy in todo_all
    }
    report = BuildReport(str(store), str(sidecar_path(store)))
    local: BackendCache = {}  # the backends of this process, when it runs the tasks itself
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
        with MapFeatureStore(sidecar_path(store), writable=True) as sidecar:
            for strategy in strategies:
                if client is not None:
                    facts = client.submit(_set_facts, strategy, settings_json, pure=False).result()
                else:
                    facts = _set_facts(strategy, settings_json, local)
                photometric = _photometric(strategy, settings_json)
                set_id = set_id_for(
                    facts.extractor_sha256,
                    facts.provider,
                    facts.multiple,
                    photometric,
                    facts.border_erode_px,
                    window_px,
                )
                existing = sidecar.feature_set(set_id)
                if existing is not None and existing.stride_px != stride:
                    raise ValueError(
                        f"{sidecar.path}: set {set_id[:12]}... was built with a stride of "
                        f"{existing.stride_px} px, not {stride}; remove the sidecar first"
                    )
                sidecar.ensure_set(
                    FeatureSet(
                        set_id,
                        facts.extractor_sha256,
                        facts.provider,
                        facts.multiple,
                        photometric,
                        facts.border_erode_px,
                        window_px,
                        stride,
                        facts.descriptor_dim,
                        strategy,
                        descriptor_dtype=facts.descriptor_dtype,
                    )
                )
                done = sidecar.done_windows(set_id)
                todo = [k for k in todo_all if done.get(k) != wanted[k]]
                skipped = len(todo_all) - len(todo)
                say(
                    f"features {strategy}: {len(todo_all)} windows of {window_px} px "
                    f"(stride {stride} px), {skipped} already done, {len(todo)} to extract "
                    f"({set_id[:12]}...)"
                )
                started = time.perf_counter()
                busy_s = 0.0
                written = 0
                args = (str(store.resolve()), strategy, settings_json, window_px, stride)
                batches = list(_batches(todo, batch_size))
                if client is not None:
                    from dask.distributed import as_completed

                    futures = [client.submit(_task, *args, b, pure=False) for b in batches]
                    results: Iterator[Any] = (f.result() for f in as_completed(futures))
                else:
                    results = (_task(*args, b, local) for b in batches)
                for rows, seconds in results:
                    sidecar.put_windows(set_id, rows)
                    busy_s += seconds
                    written += len(rows)
                    elapsed = time.perf_counter() - started
                    say(
                        f"features {strategy}: {written}/{len(todo)} windows, "
                        f"{written / max(elapsed, 1e-9):.2f} windows/s"
                    )
                elapsed = time.perf_counter() - started
                cores = _cores(client, workers)
                sidecar.mark(set_id, complete=True, windows=len(sidecar.done_windows(set_id)))
                report.strategies[strategy] = {
                    "set_id": set_id,
                    "window_px": window_px,
                    "stride_px": stride,
                    "windows": len(todo_all),
                    "skipped": skipped,
                    "extracted": written,
                    "seconds": elapsed,
                    "worker_seconds": busy_s,
                    "cores": cores,
                    "windows_per_s": written / elapsed if elapsed > 0 else 0.0,
                    "windows_per_s_per_core": (written / elapsed / cores) if elapsed > 0 else 0.0,
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
