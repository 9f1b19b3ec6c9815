"""What a map-feature build runs in a worker (a Dask worker process, or the building process
itself): the strategy's feature backend, built once per process on that process's plugin host
with the engine's whole top-K (``EXTRACT_BUDGET``) and no tile cache; the facts that key its
feature set; a batch of windows extracted exactly as the flight extracts a candidate with that
window (window px)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from c3_matcher.config import C3Settings
from c3_matcher.errors import InvalidInputError
from c3_matcher.plugins.manager import PluginHost
from c3_matcher.prepared import InputRule
from c3_matcher.protocols import StoredFeaturesBackend
from c3_matcher.stages.extract import extract_checked
from c3_matcher.tilestore.features import (
    WindowFeatures,
    covered_tiles,
    set_id_for,
    stored_tile_digest,
    window_digest,
)
from c3_matcher_tools.features.windows import WindowKey

__all__ = [
    "EXTRACT_BUDGET",
    "NotStorableError",
    "ProcessBackends",
    "SetFacts",
    "check_window",
    "extract_window_features",
    "open_source",
    "photometric_of",
    "set_facts",
    "set_facts_task",
    "task",
]

EXTRACT_BUDGET = 8192  # keep the engine's whole top-K per window (capped by the graph's K)


@dataclass(frozen=True)
class SetFacts:
    """What keys a strategy's set, learnt from its backend in a worker (and its input rule,
    which the build checks its window against before the sidecar is touched)."""

    extractor_sha256: str
    provider: str
    multiple: int
    border_erode_px: int
    descriptor_dim: int
    descriptor_dtype: str
    input_rule: InputRule

    def keyed(self, photometric: str, window_px: int) -> tuple[str, str, int, str, int, int]:
        """What the id of its set of ``window_px`` windows digests, in ``FeatureSet``'s order."""
        return (
            self.extractor_sha256,
            self.provider,
            self.multiple,
            photometric,
            self.border_erode_px,
            window_px,
        )

    def set_id(self, photometric: str, window_px: int) -> str:
        """The id of its set of ``window_px`` windows: the one a flight asks for."""
        return set_id_for(*self.keyed(photometric, window_px), self.input_rule.upscale)


@dataclass(frozen=True)
class ProcessBackends:
    """The feature backends one process runs a build's tasks with, each built once per strategy
    and settings on ``host``, that process's plugin host: the building process's own (its
    command's) when it runs the tasks itself, a Dask worker process's discovered there."""

    host: PluginHost
    held: dict[tuple[str, str], Any] = field(default_factory=dict)

    def backend(self, strategy: str, settings_json: str) -> Any:
        """The strategy's FeatureBackend with the whole top-K and no tile cache."""
        key = (strategy, settings_json)
        if key not in self.held:
            from loguru import logger

            from c3_matcher_tools.run.matcher import Overrides, open_backend

            logger.remove()
            self.held[key] = open_backend(
                C3Settings.model_validate_json(settings_json),
                strategy,
                plugin_host=self.host,
                overrides=Overrides(max_keypoints=EXTRACT_BUDGET, tile_cache_size=0),
            )
        return self.held[key]


def _backend(strategy: str, settings_json: str, local: ProcessBackends | None) -> Any:
    """The strategy's backend from ``local`` (the caller's, when it runs the tasks itself), else
    from the backends of the Dask worker running the task."""
    return (local if local is not None else _worker_backends()).backend(strategy, settings_json)


def _worker_backends() -> ProcessBackends:
    """The backends of the Dask worker running the task: one per worker process, on a plugin
    host discovered there once (the worker is another process)."""
    from dask.distributed import get_worker

    from c3_matcher.compose import build_plugin_host

    extensions = get_worker().extensions
    if "c3_feature_backends" not in extensions:
        extensions["c3_feature_backends"] = ProcessBackends(build_plugin_host())
    held: ProcessBackends = extensions["c3_feature_backends"]
    return held


def photometric_of(settings_json: str) -> str:
    """The photometric normalisation of settings resolved for a strategy
    (``c3_matcher.compose.strategy_settings``: ``[matcher] photometric``, or when unset the
    strategy's own default)."""
    return str(C3Settings.model_validate_json(settings_json).matcher.photometric)


def _preprocessor(backend: Any, photometric: str) -> Any:
    """The flight's tile preprocessing (``PipelineMatcher``'s default preprocessor)."""
    from c3_matcher.preprocess import FramePreprocessor

    return FramePreprocessor(backend.input_rule, photometric=photometric)


def check_window(rule: InputRule, window_px: int, strategy: str | None = None) -> None:
    """InvalidInputError naming ``--window`` when the input ``rule`` would pad or resize a
    ``window_px`` px window (the flight serves no stored features for it): the one place of the
    rule, checked by the build before the sidecar is touched and by each worker's window."""
    if rule.final_size(window_px, window_px) == (window_px, window_px):  # as prepare_tile sizes
        return
    whose = f" of strategy {strategy!r}" if strategy else ""
    raise InvalidInputError(
        "--window",
        f"{window_px} px would be padded or resized by the input rule{whose}: a window must be "
        f"a multiple of {rule.multiple} px and at most {rule.max_long_side} px",
    )


def extract_window_features(
    backend: Any,
    source: Any,
    zoom: int,
    origin: tuple[int, int],
    window_px: int,
    photometric: str,
) -> WindowFeatures:
    """The features of the ``window_px`` window of WORLD px whose top-left pixel is ``origin``,
    exactly as the flight extracts a candidate with that window (window px); InvalidInputError
    when the input rule would resize or pad the window (:func:`check_window`)."""
    from c3_matcher.tilestore.handles import stitch

    check_window(backend.input_rule, window_px)
    keys = covered_tiles(zoom, origin, (window_px, window_px))
    digest = window_digest(keys, lambda k: stored_tile_digest(source, k))
    image = stitch(source, zoom, origin, (window_px, window_px), f"window {zoom}/{origin}")
    prepared = _preprocessor(backend, photometric).prepare_tile(image)
    f = extract_checked(backend, prepared)  # a store holds only what a flight would take
    return WindowFeatures(
        digest,
        np.ascontiguousarray(f.keypoints, dtype=np.float32),
        np.ascontiguousarray(f.keypoint_scores, dtype=np.float32),
        np.ascontiguousarray(f.descriptors),  # the backend's dtype, never cast
    )


def open_source(store_path: str) -> Any:
    from c3_matcher.tilestore.mbtiles import MBTilesStore

    return MBTilesStore(store_path)


def task(
    store_path: str,
    strategy: str,
    settings_json: str,
    window_px: int,
    stride_px: int,
    windows: Sequence[WindowKey],
    local: ProcessBackends | None = None,
) -> tuple[list[tuple[int, int, int, WindowFeatures]], float]:
    """A worker's batch: [(zoom, gx, gy, features)] and the seconds it took (a window no stored
    tile overlaps has no features and is left out); ``local``: the backends of the process that
    runs it itself (None: the Dask worker's)."""
    from c3_matcher.tilestore.handles import TileNotFoundError

    started = time.perf_counter()
    backend = _backend(strategy, settings_json, local)
    photometric = photometric_of(settings_json)
    source = open_source(store_path)
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


class NotStorableError(ValueError):
    """A strategy whose features no store can hold: none of its own extractor engine."""


def set_facts_task(strategy: str, settings_json: str) -> SetFacts | str:
    """:func:`set_facts` as a Dask task: a refusal comes back as its message (raised, the worker
    would log it as a failed computation, traceback and all, before the build says it)."""
    try:
        return set_facts(strategy, settings_json)
    except NotStorableError as exc:
        return str(exc)


def set_facts(strategy: str, settings_json: str, local: ProcessBackends | None = None) -> SetFacts:
    """The facts keying a strategy's set, in a worker (the descriptor size from a probe;
    ``local``: the backends of the process that learns them itself, None: the Dask worker's);
    :class:`NotStorableError` for a strategy whose features come from no extractor engine."""
    backend = _backend(strategy, settings_json, local)
    sha = _extractor_sha256(strategy, backend)
    from c3_matcher.prepared import PreparedImage

    probe = np.kron(
        np.random.default_rng(0).integers(0, 256, (22, 22, 3), dtype=np.uint8),
        np.ones((6, 6, 1), np.uint8),
    )[:128, :128]
    f = backend.extract(
        PreparedImage(np.ascontiguousarray(probe), np.ones((128, 128), bool), np.eye(3), (128, 128))
    )
    photometric = photometric_of(settings_json)
    return SetFacts(
        sha,
        str(backend.provenance()["provider"]),
        int(backend.input_rule.multiple),
        int(_preprocessor(backend, photometric).border_erode_px),
        int(f.descriptors.shape[1]),
        str(f.descriptors.dtype),
        backend.input_rule,
    )


def _extractor_sha256(strategy: str, backend: Any) -> str:
    """The extractor engine's sha256 a ``StoredFeaturesBackend`` declares: what its stored
    features are keyed by; :class:`NotStorableError` for a backend that declares none (OpenCV
    SIFT extracts without an engine)."""
    sha = backend.extractor_sha256 if isinstance(backend, StoredFeaturesBackend) else None
    if not sha:
        raise NotStorableError(
            f"strategy {strategy!r} names no extractor engine its features come from (its "
            f"backend, {backend.provenance()['provider']}, declares no extractor_sha256), so "
            "no stored features serve it: its tiles are extracted in flight; build them for a "
            "strategy that has one"
        )
    return str(sha)
