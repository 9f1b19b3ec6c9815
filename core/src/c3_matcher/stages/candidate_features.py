"""Steps 4a-4b: a candidate's tile features, from the first source that has them: the tile
store's precomputed map features (``stored``, when the backend declares them possible and the
store holds them for this backend), the tile cache (``cached``) or the tile's pixels
(``extracted``: decode within the matcher's pixel limit, prepare, extract; the cache keeps the
result, keyed by the bytes decoded: read again once extracted, a tile rewritten meanwhile is not
cached). A store whose sidecar holds map features but no set for this backend is said once per
store and set (a WARNING): its candidates are extracted, as a store without a sidecar's are,
silently."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Final

from c3_matcher.dto import RerankCandidate, TileId
from c3_matcher.features import Features
from c3_matcher.prepared import PreparedImage
from c3_matcher.preprocess import FramePreprocessor
from c3_matcher.protocols import FeatureBackend, StoredFeaturesBackend, StoredFeaturesHandle
from c3_matcher.stages.extract import Extraction, backend_budget, checked_features
from c3_matcher.stages.failure import failing_as, timed
from c3_matcher.stages.interrupts import is_stop
from c3_matcher.stages.outcomes import TileFeatures
from c3_matcher.stages.provenance import read_provenance
from c3_matcher.stages.recorder import FrameRecorder
from c3_matcher.tile_cache import CachedTile, TileFeatureCache, tile_cache_key
from c3_matcher.tile_limit import decode_within
from c3_matcher.tiles import DEFAULT_MAX_IMAGE_PIXELS
from c3_matcher.tilestore.features import FeatureRequest, NoStoredSet, StoredWindowHandle

__all__ = ["TILE_DECODE_PHASE", "CandidateFeatures", "feature_request"]

TILE_DECODE_PHASE = "tile_decode"
"""The step that reads and checks a candidate's tile from its handle (its sha256, its decoding):
a backbone error there is the tile's own, not the matcher's."""


def feature_request(backend: FeatureBackend, pre: FramePreprocessor) -> FeatureRequest | None:
    """What to ask a tile store's precomputed features for: the extractor engine (file sha256)
    the backend declares, its execution provider (its provenance's), input rule, photometric
    normalisation and keypoint budget; None for a backend that is no ``StoredFeaturesBackend``,
    names no extractor engine or keeps no keypoint (its tiles are then always extracted)."""
    if not isinstance(backend, StoredFeaturesBackend):
        return None
    sha, budget, rule = backend.extractor_sha256, backend_budget(backend), backend.input_rule
    if not isinstance(sha, str) or not sha or budget is None:
        return None
    provider = str(read_provenance(backend).get("provider") or "")  # it may fail: none
    return FeatureRequest(
        sha,
        rule.multiple,
        rule.max_long_side,
        budget,
        pre.border_erode_px,
        pre.photometric,
        provider,
        rule.upscale,
    )


class CandidateFeatures:
    """The candidate-features source of one matcher: stored, cached or extracted features.
    ``use_stored`` False (``[matcher] stored_features``): never the store's; True: the store's
    when it has them for ``request`` (None: this backend's tiles are always extracted); a
    sidecar without a set for ``request`` is said once for the matcher's life; a tile is decoded
    within ``max_pixels`` (:func:`~c3_matcher.tile_limit.decode_within`) and extracted by
    ``extraction`` (the matcher's: checked, cut to the keypoint budget). Single-threaded."""

    def __init__(
        self,
        extraction: Extraction,
        pre: FramePreprocessor,
        cache: TileFeatureCache,
        request: FeatureRequest | None,
        use_stored: bool,
        max_pixels: int = DEFAULT_MAX_IMAGE_PIXELS,
    ) -> None:
        self._extraction = extraction
        self._pre = pre
        self.cache: Final = cache
        self.request: Final = request
        self.use_stored: Final = bool(use_stored) and request is not None
        self.max_pixels: Final = max_pixels
        self._unserved: set[tuple[Path, str]] = set()  # (sidecar, set id) said already

    def fetch(
        self, candidate: RerankCandidate, recorder: FrameRecorder, timings: dict[str, float]
    ) -> TileFeatures:
        """The candidate's tile features; raises ``CandidateStepError`` (``tile_decode`` or the
        backend's extract phase) when they can be had from none of the sources."""
        with failing_as(TILE_DECODE_PHASE, "none"):
            stored = None
            if self.use_stored:
                with timed(timings, "assemble"):
                    stored = self._stored(candidate, recorder)
            if stored is not None:
                return stored
            handle = candidate.tile_pixels_handle
            key = tile_cache_key(candidate.tile_id, handle) if self.cache.enabled else None
            cached = self.cache.get(key) if key is not None else None
        if cached is not None:
            return self._tile("cached", cached.prepared, cached.features, key)
        with failing_as(TILE_DECODE_PHASE, "extracted"):
            with timed(timings, "decode"):
                pixels = decode_within(handle, self.max_pixels, f"tile {candidate.tile_id}")
            with timed(timings, "preprocess"):
                image = self._pre.prepare_tile(pixels)
        phase = self._extraction.backend.extract_phase
        with failing_as(phase, "extracted"), timed(timings, "extract"):
            features = self._extraction(image)
        if key is not None and _unchanged(candidate, key):
            self.cache.put(key, CachedTile(image, features))
        return self._tile("extracted", image, features, key)

    def _tile(
        self, source: str, image: PreparedImage, features: Features, key: tuple[TileId, str] | None
    ) -> TileFeatures:
        """A tile's features from ``source``; one the cache may hold under ``key`` leaves it
        when a frame refuses or cannot match them (``TileFeatures.forget``)."""
        if key is None:  # the cache is off
            return TileFeatures(source, image, features)
        return TileFeatures(source, image, features, functools.partial(self.cache.discard, key))

    def _stored(self, candidate: RerankCandidate, recorder: FrameRecorder) -> TileFeatures | None:
        """The candidate's precomputed map features, or None (extract): a handle without
        stored features, no or stale stored features, a window the rule would resize. A
        failure here never drops the candidate: it falls back to extraction; the store raises
        once per outage (locked sidecar) or corrupt row, so the WARNING (and its FDR record)
        comes once, not every frame."""
        assert self.request is not None  # use_stored: a request was made
        try:
            features = _served(candidate, self.request)
            if isinstance(features, NoStoredSet):
                self._said_unserved(features, recorder)
            if not isinstance(features, Features):
                return None
            geometry = self._pre.tile_geometry(*features.image_size)
            if geometry is not None:  # held to the rule an extraction is held to
                checked_features(features, geometry.engine_size, "stored window")
        except BaseException as exc:  # a plugin's own BaseException too: still extracted
            if is_stop(exc):  # Ctrl-C, a signal handler's exit: they go on
                raise
            recorder.stored_features_failed(candidate.tile_id, exc)
            return None
        return None if geometry is None else TileFeatures("stored", geometry, features)

    def _said_unserved(self, unserved: NoStoredSet, recorder: FrameRecorder) -> None:
        """Say once per sidecar and set id that the store holds no set for this backend (its
        candidates are extracted): never per frame."""
        key = (unserved.sidecar, unserved.asked)
        if key not in self._unserved:
            self._unserved.add(key)
            recorder.stored_features_unserved(unserved)


def _served(candidate: RerankCandidate, request: FeatureRequest) -> object:
    """What the candidate's handle serves for ``request``: its stored features, NoStoredSet
    (a handle that says why it has none) or None (a handle without stored features)."""
    handle = candidate.tile_pixels_handle
    if isinstance(handle, StoredWindowHandle):
        return handle.stored_window(request)
    if isinstance(handle, StoredFeaturesHandle):
        return handle.stored_features(request)
    return None


def _unchanged(candidate: RerankCandidate, key: tuple[object, str]) -> bool:
    """The candidate's tile bytes, read again, still have ``key``'s digest: the pixels just
    decoded are those the key names (a tile file rewritten between the two reads is not cached
    under the old bytes' key; a handle that fails now is simply not cached)."""
    try:
        return tile_cache_key(candidate.tile_id, candidate.tile_pixels_handle) == key
    except BaseException as exc:  # any handle's failure: the features were had, not cached
        if is_stop(exc):  # Ctrl-C, a signal handler's exit: they go on
            raise
        return False
