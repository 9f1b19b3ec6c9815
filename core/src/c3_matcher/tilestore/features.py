"""Map features computed once on the ground: the sidecar store and the flight read path.

A candidate's features are a function of the WHOLE image the extractor sees (XFeat normalises
the whole input, DISK's U-Net sees hundreds of px, the top-K and the photometric normalisation
are per image), so features stitched from separately extracted tiles are not the window's own.
The store therefore holds whole candidate WINDOWS: ``c3-matcher features build`` extracts, for a
grid of ``window_px`` square windows of WORLD px whose top-left pixel is a multiple of
``stride_px`` (``(gx * stride_px, gy * stride_px)``), exactly what the flight extracts for a
candidate with that window: the stitched window, the flight's ``FramePreprocessor
.prepare_tile`` (valid mask, border erosion, photometric normalisation) and the strategy's own
engine, keeping every keypoint the engine outputs (best score first). In flight a candidate whose
window IS a grid window gets those features bit for bit; any keypoint budget is their prefix
(the extractor keeps the best by a stable sort). A candidate off the grid is served the nearest
grid window's features (at most ``stride_px / 2`` px away on each axis: the re-ranker's
candidates are approximate anyway) shifted into its own px: those the shift leaves on its
window, best first (the strip of it the grid window does not show has none), so they pass the
flight's check that keypoints lie on the image they describe.

Sidecar database ``<store>.features.sqlite``::

    window_sets (set_id TEXT PRIMARY KEY, extractor_sha256, provider, multiple, photometric,
                 border_erode_px, window_px, stride_px, descriptor_dim, strategy, complete,
                 windows, descriptor_dtype, created)
    window_features (set_id, zoom, gx, gy, window_digest, n, keypoints, scores, descriptors,
                     checksum, PRIMARY KEY (set_id, zoom, gx, gy))

A set is keyed by everything the extraction depends on: the extractor engine's file sha256, the
execution provider, the input rule's size multiple (and its upscale, when not 1: in the set's key),
the photometric normalisation, the border erosion and the window size: features of another engine
build, device or preprocessing are never served. ``window_digest`` is the sha256 of the sha256
digests of the tiles the window covers (a window whose tiles changed is never served stale);
``checksum`` the sha256 of the row itself (a row altered on disk, even into finite numbers, is
refused). Keypoints are float32 (n, 2) (x, y) in window px (origin at the centre of its top-left
pixel), scores float32 (n,), descriptors (n, D) of the backend's own dtype (``descriptor_dtype``:
float32, or uint8 for packed binary descriptors), never cast.

Reliability in flight: the read connection never waits on a lock (busy timeout 0). When the
sidecar is locked, unreadable or does not answer a read within ``bounded.READ_S`` (a view
that never ends) the store says so once (:class:`FeatureStoreUnavailableError`),
then serves nothing for ``retry_s`` seconds (the pipeline extracts) and tries again; a corrupt
row (checksum, shapes, or database pages SQLite finds malformed) is refused once
(:class:`StoredFeaturesCorruptError`, naming the window) and never served. The ground writer
leaves the sidecar one self-contained file (no WAL), readable from read-only media; one an older
version left in WAL mode is read there as an immutable file (nothing can write it:
:func:`~c3_matcher.tilestore.files.unchanging`), and where its ``-shm`` cannot be made otherwise
the outage says so, and that ``features build`` makes it one file.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from c3_matcher.features import Features
from c3_matcher.tilestore.sidecar import (
    FEATURES_SUFFIX,
    FeatureStoreUnavailableError,
    MapFeatureStore,
    StoredFeaturesCorruptError,
    sidecar_path,
)
from c3_matcher.tilestore.windows import (
    FeatureRequest,
    FeatureSet,
    WindowFeatures,
    covered_tiles,
    grid_index,
    row_checksum,
    set_id_for,
    stored_tile_digest,
    tile_digest,
    window_digest,
)

__all__ = [
    "FEATURES_SUFFIX",
    "FeatureRequest",
    "FeatureSet",
    "FeatureStoreUnavailableError",
    "MapFeatureStore",
    "NoStoredSet",
    "StoredFeaturesCorruptError",
    "StoredWindowHandle",
    "WindowFeatures",
    "covered_tiles",
    "features_only",
    "grid_index",
    "row_checksum",
    "served_window",
    "set_id_for",
    "sidecar_path",
    "stored_sets",
    "stored_tile_digest",
    "tile_digest",
    "window_digest",
]


@runtime_checkable
class FeatureSource(Protocol):
    """A slippy tile store that may serve stored features (``feature_store`` returns None when
    it has none)."""

    def tile_bytes(self, zoom: int, x: int, y: int) -> memoryview | None: ...

    def feature_store(self) -> MapFeatureStore | None: ...


@dataclass(frozen=True)
class NoStoredSet:
    """A sidecar of map features that holds no set for a flight's request: its path, the set
    id the request asks for (``asked``) and the ids of the sets it holds (``held``); the
    candidate is extracted. A setting that keys the sets (an engine, provider, photometric
    normalisation, window size, upscale) other than those a build ran with is the usual cause."""

    sidecar: Path
    asked: str
    held: tuple[str, ...]

    def __str__(self) -> str:
        held = ", ".join(self.held) or "none"
        return (
            f"{self.sidecar} holds no set {self.asked}, the one these settings ask for (it "
            f"holds: {held}); the candidates of its store are extracted instead"
        )

    def as_record(self) -> dict[str, Any]:
        """Its fields as a log event carries them."""
        return {
            "sidecar": str(self.sidecar),
            "asked_set_id": self.asked,
            "held_set_ids": list(self.held),
        }


@runtime_checkable
class StoredWindowHandle(Protocol):
    """A tile handle that says why a store serves it no features (the MBTiles handles):
    ``stored_window(request)`` is its features, :class:`NoStoredSet` or None, as
    :func:`served_window` gives them."""

    def stored_window(self, request: FeatureRequest) -> Features | NoStoredSet | None: ...


def features_only(served: Features | NoStoredSet | None) -> Features | None:
    """``served`` when it is features, else None (no set for the request: extract)."""
    return served if isinstance(served, Features) else None


def served_window(
    source: FeatureSource,
    request: FeatureRequest,
    zoom: int,
    origin: tuple[int, int],
    size: tuple[int, int],
) -> Features | NoStoredSet | None:
    """The stored features of the (w, h) = ``size`` window of WORLD px whose top-left pixel is
    ``origin``, in its own px: those of the nearest grid window of a set matching ``request``
    (exactly the window's when it is on the grid; off it, those on this window:
    :func:`_shifted_onto`), the ``request.max_keypoints`` best. :class:`NoStoredSet` when the
    store has a sidecar without that set, None when it has none, or no such window, the
    window's tiles changed since, or the input rule would resize or pad it (the caller extracts
    in each case). Raises FeatureStoreUnavailableError / StoredFeaturesCorruptError once per
    outage / corrupt row (see :class:`MapFeatureStore`)."""
    w, h = int(size[0]), int(size[1])
    if w != h or w > request.max_long_side or w % request.multiple:
        return None
    store = source.feature_store()
    if store is None:
        return None
    asked = request.set_id(w)
    fset = store.feature_set(asked)
    if fset is None:
        return _no_set(store, asked)
    gx, gy = grid_index(origin, fset.stride_px)
    stored = store.window(fset, zoom, gx, gy)
    if stored is None:
        return None
    grid_origin = (gx * fset.stride_px, gy * fset.stride_px)
    keys = covered_tiles(zoom, grid_origin, (w, h))
    digest = window_digest(keys, lambda key: stored_tile_digest(source, key))
    if digest != stored.window_digest:
        return None  # the tiles changed since the build: stale
    shift = (grid_origin[0] - int(origin[0]), grid_origin[1] - int(origin[1]))
    return _shifted_onto(stored, shift, (w, h), int(request.max_keypoints))


def _no_set(store: MapFeatureStore, asked: str) -> NoStoredSet | None:
    """What the sidecar ``store`` holds instead of the set ``asked``; None when that cannot be
    told (an outage) or the set is there but unreadable (a damaged row, said once already)."""
    held = store.set_ids()
    if held is None or asked in held:
        return None
    return NoStoredSet(store.path, asked, held)


def _shifted_onto(
    stored: WindowFeatures, shift: tuple[int, int], size: tuple[int, int], budget: int
) -> Features:
    """``stored``'s features moved by ``shift`` (px) into a (w, h) = ``size`` window's px, the
    ``budget`` best of those on it: a keypoint the shift takes off the window (the part of the
    grid window the candidate does not show) is left out, the rest kept in their order (best
    first), so a candidate off the grid gets what lies on it, as its extraction would."""
    keypoints, descriptors, scores = stored.keypoints, stored.descriptors, stored.scores
    if shift != (0, 0):  # off the grid: the nearest window's features, in this window's px
        keypoints = keypoints + np.array(shift, dtype=np.float32)
        high = np.array(size, dtype=np.float32) - 0.5
        on = ((keypoints >= -0.5) & (keypoints <= high)).all(axis=1)
        keypoints, descriptors, scores = keypoints[on], descriptors[on], scores[on]
    n = min(budget, scores.shape[0])
    return Features(
        keypoints=np.ascontiguousarray(keypoints[:n], dtype=np.float32),
        descriptors=np.ascontiguousarray(descriptors[:n]),
        keypoint_scores=np.ascontiguousarray(scores[:n], dtype=np.float32),
        image_size=size,
    )


def stored_sets(store: MapFeatureStore) -> Iterator[Mapping[str, Any]]:
    """The sets of a sidecar as dicts (for ``features info``; ``windows``: those stored, also
    in a set a stopped build left incomplete; ``extractor_sha256``: the engine file that
    extracted them, which the flight's must be to be served them)."""
    for s in store.feature_sets():
        yield {
            "set_id": s.set_id,
            "strategy": s.strategy,
            "extractor_sha256": s.extractor_sha256,
            "provider": s.provider,
            "photometric": s.photometric,
            "window_px": s.window_px,
            "stride_px": s.stride_px,
            "descriptor_dim": s.descriptor_dim,
            "descriptor_dtype": s.descriptor_dtype,
            "complete": s.complete,
            "windows": len(store.done_windows(s.set_id)),
        }
