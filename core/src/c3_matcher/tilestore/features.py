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
candidates are approximate anyway) shifted into its own px.

Sidecar database ``<store>.features.sqlite``::

    window_sets (set_id TEXT PRIMARY KEY, extractor_sha256, provider, multiple, photometric,
                 border_erode_px, window_px, stride_px, descriptor_dim, strategy, complete,
                 windows, descriptor_dtype, created)
    window_features (set_id, zoom, gx, gy, window_digest, n, keypoints, scores, descriptors,
                     checksum, PRIMARY KEY (set_id, zoom, gx, gy))

A set is keyed by everything the extraction depends on: the extractor engine's file sha256, the
execution provider, the input rule's size multiple, the photometric normalisation, the border
erosion and the window size: features of another engine build, device or preprocessing are
never served. ``window_digest`` is the sha256 of the sha256 digests of the tiles the window
covers (a window whose tiles changed is never served stale); ``checksum`` the sha256 of the row
itself (a row altered on disk, even into finite numbers, is refused). Keypoints are float32 (n, 2)
(x, y) in window px (origin at the centre of its top-left pixel), scores float32 (n,),
descriptors (n, D) of the backend's own dtype (``descriptor_dtype``: float32, or uint8 for
packed binary descriptors), never cast.

Reliability in flight: the read connection never waits on a lock (busy timeout 0). When the
sidecar is locked or unreadable the store says so once (:class:`FeatureStoreUnavailableError`),
then serves nothing for ``retry_s`` seconds (the pipeline extracts) and tries again; a corrupt
row is refused once (:class:`StoredFeaturesCorruptError`) and never served.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import sqlite3
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from c3_matcher.features import Features
from c3_matcher.tilestore.geo import TILE_PX

__all__ = [
    "FEATURES_SUFFIX",
    "FeatureRequest",
    "FeatureSet",
    "FeatureStoreUnavailableError",
    "MapFeatureStore",
    "StoredFeaturesCorruptError",
    "WindowFeatures",
    "covered_tiles",
    "grid_index",
    "row_checksum",
    "serve_window",
    "set_id_for",
    "sidecar_path",
    "stored_sets",
    "tile_digest",
    "window_digest",
]

FEATURES_SUFFIX = ".features.sqlite"
DEFAULT_RETRY_S = 30.0  # a locked or unreadable sidecar is tried again after this long
MMAP_BYTES = 256 * 1024 * 1024  # the read connection's memory map (as the tile store's)
PAGE_BYTES = 65536  # SQLite page size of a new sidecar (a row is about a megabyte)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS window_sets (
    set_id TEXT PRIMARY KEY, extractor_sha256 TEXT NOT NULL, provider TEXT NOT NULL,
    multiple INTEGER NOT NULL, photometric TEXT NOT NULL, border_erode_px INTEGER NOT NULL,
    window_px INTEGER NOT NULL, stride_px INTEGER NOT NULL, descriptor_dim INTEGER NOT NULL,
    strategy TEXT NOT NULL, complete INTEGER NOT NULL DEFAULT 0,
    windows INTEGER NOT NULL DEFAULT 0, descriptor_dtype TEXT NOT NULL, created TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS window_features (
    set_id TEXT NOT NULL, zoom INTEGER NOT NULL, gx INTEGER NOT NULL, gy INTEGER NOT NULL,
    window_digest TEXT NOT NULL, n INTEGER NOT NULL, keypoints BLOB NOT NULL,
    scores BLOB NOT NULL, descriptors BLOB NOT NULL, checksum TEXT NOT NULL,
    PRIMARY KEY (set_id, zoom, gx, gy)) WITHOUT ROWID;
"""

_SET_COLUMNS = (
    "set_id, extractor_sha256, provider, multiple, photometric, border_erode_px, window_px, "
    "stride_px, descriptor_dim, strategy, complete, windows, descriptor_dtype"
)

T = TypeVar("T")


class FeatureStoreUnavailableError(RuntimeError):
    """The sidecar is locked by another process or unreadable: raised once per outage (the
    store then serves nothing until it is tried again)."""


class StoredFeaturesCorruptError(RuntimeError):
    """A stored row does not match its checksum (or cannot be decoded): raised once per row,
    which is never served."""


def sidecar_path(store_path: str | Path) -> Path:
    """``<store>.features.sqlite`` beside the tile store."""
    p = Path(store_path)
    return p.with_name(p.name + FEATURES_SUFFIX)


def tile_digest(blob: bytes | memoryview) -> str:
    """sha256 (hex) of a tile's encoded bytes (as a tile store's ``c3_tile_digest`` table)."""
    return hashlib.sha256(blob).hexdigest()


def covered_tiles(
    zoom: int, origin: tuple[int, int], size: tuple[int, int]
) -> list[tuple[int, int, int]]:
    """XYZ keys (zoom, x, y) of the tiles the (w, h) = ``size`` window of WORLD px whose top-left
    pixel is ``origin`` covers, row-major (x wraps around the antimeridian, rows off the map are
    left out), as :func:`~c3_matcher.tilestore.handles.stitch` reads them."""
    x0, y0 = int(origin[0]), int(origin[1])
    w, h = int(size[0]), int(size[1])
    n = 1 << zoom
    return [
        (zoom, tx % n, ty)
        for ty in range(y0 // TILE_PX, (y0 + h - 1) // TILE_PX + 1)
        if 0 <= ty < n
        for tx in range(x0 // TILE_PX, (x0 + w - 1) // TILE_PX + 1)
    ]


def window_digest(
    keys: Iterable[tuple[int, int, int]], digest_of: Callable[[tuple[int, int, int]], str | None]
) -> str:
    """sha256 (hex) of the digests of a window's tiles ``keys`` (``digest_of`` returns None for a
    missing tile): the window's pixels changed iff this changed."""
    h = hashlib.sha256()
    for key in keys:
        h.update(f"{key[0]}/{key[1]}/{key[2]}={digest_of(key) or '-'};".encode())
    return h.hexdigest()


def set_id_for(
    extractor_sha256: str,
    provider: str,
    multiple: int,
    photometric: str,
    border_erode_px: int,
    window_px: int,
) -> str:
    """A window set's key: everything a window's extraction depends on (module docstring)."""
    return (
        f"{extractor_sha256}:{provider}:hw{int(multiple)}:{photometric}:"
        f"e{int(border_erode_px)}:w{int(window_px)}"
    )


@dataclass(frozen=True, slots=True)
class FeatureRequest:
    """What the flight read path asks for: the extractor engine (file sha256) and the execution
    provider it runs on, its input rule (``multiple``, ``max_long_side``), the keypoint budget,
    the valid-mask erosion (px) and the photometric normalisation of the flight's
    preprocessing."""

    extractor_sha256: str
    multiple: int
    max_long_side: int
    max_keypoints: int
    border_erode_px: int = 4
    photometric: str = "none"
    provider: str = "CPUExecutionProvider"

    def set_id(self, window_px: int) -> str:
        """The key of the set holding ``window_px`` windows for this request."""
        return set_id_for(
            self.extractor_sha256,
            self.provider,
            self.multiple,
            self.photometric,
            self.border_erode_px,
            window_px,
        )


@dataclass(frozen=True, slots=True)
class FeatureSet:
    """One set of stored windows (module docstring); ``complete`` once a build finished."""

    set_id: str
    extractor_sha256: str
    provider: str
    multiple: int
    photometric: str
    border_erode_px: int
    window_px: int
    stride_px: int
    descriptor_dim: int
    strategy: str
    complete: bool = False
    windows: int = 0
    descriptor_dtype: str = "float32"  # or "uint8" (packed binary descriptors)


@dataclass(frozen=True, slots=True)
class WindowFeatures:
    """One window's stored features (window px, best score first) and the digest of the tiles
    they came from."""

    window_digest: str
    keypoints: NDArray[np.float32]
    scores: NDArray[np.float32]
    descriptors: NDArray[Any]  # float32, or uint8 (packed binary descriptors)

    def blobs(self) -> tuple[bytes, bytes, bytes]:
        """The three arrays as stored, C order: keypoints and scores float32, descriptors in
        their own dtype."""
        return (
            np.ascontiguousarray(self.keypoints, dtype=np.float32).tobytes(),
            np.ascontiguousarray(self.scores, dtype=np.float32).tobytes(),
            np.ascontiguousarray(self.descriptors).tobytes(),
        )


def row_checksum(
    key: tuple[str, int, int, int], digest: str, n: int, blobs: Iterable[bytes | memoryview]
) -> str:
    """sha256 (hex) of a stored row: its key (set, zoom, gx, gy), window digest, count and the
    three arrays' bytes as stored."""
    h = hashlib.sha256()
    h.update(f"{key[0]}|{key[1]}|{key[2]}|{key[3]}|{digest}|{n}|".encode())
    for blob in blobs:
        h.update(blob)
    return h.hexdigest()


class MapFeatureStore:
    """The sidecar database: read-only and never waiting on a lock by default (the flight);
    ``writable=True`` for the ground command (the single writer)."""

    def __init__(
        self,
        path: str | Path,
        *,
        writable: bool = False,
        retry_s: float = DEFAULT_RETRY_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.path = Path(path)
        self._retry_s = float(retry_s)
        self._clock = clock
        if writable:
            self._db = sqlite3.connect(str(self.path), timeout=60)
            self._db.execute(f"PRAGMA page_size={PAGE_BYTES}")  # a new file: fewer pages a row
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.executescript(_SCHEMA)
            self._db.commit()
        else:  # busy timeout 0: a lock held elsewhere fails at once, the frame never waits
            self._db = sqlite3.connect(f"file:{self.path.resolve()}?mode=ro", uri=True, timeout=0)
            with contextlib.suppress(sqlite3.Error):  # rows read from the page cache
                self._db.execute(f"PRAGMA mmap_size={MMAP_BYTES}")
        self._sets: dict[str, FeatureSet | None] = {}
        self._down_until: float | None = None  # unavailable: nothing served before this time
        self._reported = False  # this outage was already raised
        self._refused: set[tuple[str, int, int, int]] = set()

    # -- reading ------------------------------------------------------------------------
    def _read(self, query: Callable[[], T]) -> T | None:
        """``query`` unless the store is in an outage (None); the first failure of an outage
        raises FeatureStoreUnavailableError, later ones within it return None."""
        now = self._clock()
        if self._down_until is not None and now < self._down_until:
            return None
        try:
            result = query()
        except sqlite3.Error as exc:
            self._down_until = now + self._retry_s
            self._sets.clear()
            if self._reported:
                return None
            self._reported = True
            raise FeatureStoreUnavailableError(
                f"{self.path}: {type(exc).__name__}: {exc}; extracting instead, "
                f"next try in {self._retry_s:g} s"
            ) from exc
        self._down_until, self._reported = None, False
        return result

    def feature_set(self, set_id: str) -> FeatureSet | None:
        if set_id not in self._sets:
            row = self._read(
                lambda: self._db.execute(
                    f"SELECT {_SET_COLUMNS} FROM window_sets WHERE set_id=?", (set_id,)
                ).fetchone()
            )
            if row is None and self._down_until is not None:
                return None  # unavailable: not remembered as absent
            self._sets[set_id] = None if row is None else _set_of(row)
        return self._sets[set_id]

    def feature_sets(self) -> list[FeatureSet]:
        rows = self._read(
            lambda: self._db.execute(
                f"SELECT {_SET_COLUMNS} FROM window_sets ORDER BY 1"
            ).fetchall()
        )
        return [_set_of(r) for r in rows or ()]

    def window(self, fset: FeatureSet, zoom: int, gx: int, gy: int) -> WindowFeatures | None:
        """Grid window (gx, gy) of ``fset`` at ``zoom``, verified against its checksum; None when
        not stored (or in an outage). StoredFeaturesCorruptError the first time a corrupt row is
        read, None afterwards."""
        key = (fset.set_id, zoom, gx, gy)
        if key in self._refused:
            return None
        row = self._read(
            lambda: self._db.execute(
                "SELECT window_digest, n, keypoints, scores, descriptors, checksum "
                "FROM window_features WHERE set_id=? AND zoom=? AND gx=? AND gy=?",
                key,
            ).fetchone()
        )
        if row is None:
            return None
        try:
            n, d = int(row[1]), fset.descriptor_dim
            ok = row_checksum(key, str(row[0]), n, row[2:5]) == str(row[5])
            stored = WindowFeatures(
                str(row[0]),
                np.frombuffer(row[2], dtype=np.float32).reshape(n, 2),
                np.frombuffer(row[3], dtype=np.float32).reshape(n),
                np.frombuffer(row[4], dtype=np.dtype(fset.descriptor_dtype)).reshape(n, d),
            )
        except (ValueError, TypeError) as exc:
            ok, stored = False, None
            reason = f"undecodable ({exc})"
        else:
            reason = "checksum mismatch"
        if not ok or stored is None:
            self._refused.add(key)
            raise StoredFeaturesCorruptError(
                f"{self.path}: window {zoom}/{gx}/{gy} of set {fset.set_id[:12]}...: {reason}; "
                "refused, extracting instead"
            )
        return stored

    def done_windows(self, set_id: str) -> dict[tuple[int, int, int], str]:
        """(zoom, gx, gy) -> window digest of every window stored in a set."""
        return {
            (int(z), int(x), int(y)): str(d)
            for z, x, y, d in self._db.execute(
                "SELECT zoom, gx, gy, window_digest FROM window_features WHERE set_id=?", (set_id,)
            )
        }

    # -- writing (ground) ---------------------------------------------------------------
    def ensure_set(self, fset: FeatureSet) -> None:
        self._db.execute(
            f"INSERT OR IGNORE INTO window_sets ({_SET_COLUMNS}, created) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 0, 0, ?, ?)",
            (
                fset.set_id,
                fset.extractor_sha256,
                fset.provider,
                fset.multiple,
                fset.photometric,
                fset.border_erode_px,
                fset.window_px,
                fset.stride_px,
                fset.descriptor_dim,
                fset.strategy,
                fset.descriptor_dtype,
                time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            ),
        )
        self._db.commit()
        self._sets.pop(fset.set_id, None)

    def put_windows(
        self, set_id: str, rows: Iterable[tuple[int, int, int, WindowFeatures]]
    ) -> None:
        self._db.executemany(
            "INSERT OR REPLACE INTO window_features VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [
                (
                    set_id,
                    z,
                    gx,
                    gy,
                    w.window_digest,
                    len(w.scores),
                    *blobs,
                    row_checksum((set_id, z, gx, gy), w.window_digest, len(w.scores), blobs),
                )
                for z, gx, gy, w in rows
                for blobs in (w.blobs(),)
            ],
        )
        self._db.commit()

    def mark(self, set_id: str, *, complete: bool, windows: int) -> None:
        self._db.execute(
            "UPDATE window_sets SET complete=?, windows=? WHERE set_id=?",
            (int(complete), int(windows), set_id),
        )
        self._db.commit()
        self._sets.pop(set_id, None)

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> MapFeatureStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _set_of(row: Sequence[Any]) -> FeatureSet:
    return FeatureSet(
        str(row[0]),
        str(row[1]),
        str(row[2]),
        int(row[3]),
        str(row[4]),
        int(row[5]),
        int(row[6]),
        int(row[7]),
        int(row[8]),
        str(row[9]),
        bool(row[10]),
        int(row[11]),
        str(row[12]),
    )


class FeatureSource(Protocol):
    """A slippy tile store that may serve stored features (``feature_store`` returns None when
    it has none)."""

    def tile_bytes(self, zoom: int, x: int, y: int) -> memoryview | None: ...

    def feature_store(self) -> MapFeatureStore | None: ...


def grid_index(origin: tuple[int, int], stride_px: int) -> tuple[int, int]:
    """The grid window nearest to a window whose top-left pixel is ``origin`` (WORLD px): the
    (gx, gy) with (gx, gy) * ``stride_px`` closest to it (halves round up)."""
    return (
        math.floor(origin[0] / stride_px + 0.5),
        math.floor(origin[1] / stride_px + 0.5),
    )


def serve_window(
    source: FeatureSource,
    request: FeatureRequest,
    zoom: int,
    origin: tuple[int, int],
    size: tuple[int, int],
) -> Features | None:
    """The stored features of the (w, h) = ``size`` window of WORLD px whose top-left pixel is
    ``origin``, in its own px: those of the nearest grid window of a set matching ``request``
    (exactly the window's when it is on the grid), the ``request.max_keypoints`` best. None (the
    caller extracts) when the store has no such set or window, the window's tiles changed since,
    or the input rule would resize or pad it. Raises FeatureStoreUnavailableError /
    StoredFeaturesCorruptError once per outage / corrupt row (see :class:`MapFeatureStore`)."""
    w, h = int(size[0]), int(size[1])
    if w != h or w > request.max_long_side or w % request.multiple:
        return None
    store = source.feature_store()
    if store is None:
        return None
    fset = store.feature_set(request.set_id(w))
    if fset is None:
        return None
    gx, gy = grid_index(origin, fset.stride_px)
    stored = store.window(fset, zoom, gx, gy)
    if stored is None:
        return None
    grid_origin = (gx * fset.stride_px, gy * fset.stride_px)
    keys = covered_tiles(zoom, grid_origin, (w, h))
    blobs = {k: source.tile_bytes(*k) for k in keys}
    digest = window_digest(keys, lambda k: None if blobs[k] is None else tile_digest(blobs[k]))  # type: ignore[arg-type]
    if digest != stored.window_digest:
        return None  # the tiles changed since the build: stale
    n = min(int(request.max_keypoints), stored.scores.shape[0])
    keypoints = stored.keypoints[:n]
    dx, dy = grid_origin[0] - int(origin[0]), grid_origin[1] - int(origin[1])
    if dx or dy:  # off the grid: the nearest window's features, in this window's px
        keypoints = keypoints + np.array([dx, dy], dtype=np.float32)
    return Features(
        keypoints=np.ascontiguousarray(keypoints, dtype=np.float32),
        descriptors=np.ascontiguousarray(stored.descriptors[:n]),
        keypoint_scores=np.ascontiguousarray(stored.scores[:n], dtype=np.float32),
        image_size=(w, h),
    )


def stored_sets(store: MapFeatureStore) -> Iterator[Mapping[str, Any]]:
    """The sets of a sidecar as dicts (for ``features info``)."""
    for s in store.feature_sets():
        yield {
            "set_id": s.set_id,
            "strategy": s.strategy,
            "provider": s.provider,
            "photometric": s.photometric,
            "window_px": s.window_px,
            "stride_px": s.stride_px,
            "descriptor_dim": s.descriptor_dim,
            "descriptor_dtype": s.descriptor_dtype,
            "complete": s.complete,
            "windows": s.windows,
        }
