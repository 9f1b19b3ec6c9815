"""Map features computed once on the ground: the sidecar store and the flight read path.

``c3-matcher features build STORE`` (ground tools) extracts, for every stored 256-px tile and a
strategy's extractor, the keypoints, scores and descriptors of the tile WITH a context margin of
``margin_px`` px taken from its neighbours (so a keypoint near the tile's edge sees the same
surroundings as in a larger image), keeps those in the tile's core, and writes them to a sidecar
SQLite database next to the tile store (``<store>.features.sqlite``)::

    feature_sets (set_id TEXT PRIMARY KEY, extractor_sha256, multiple, margin_px,
                  descriptor_dim, descriptor_dtype, strategy, complete, tiles, created)
    tile_features (set_id, zoom, x, y, tile_digest, n, keypoints, scores, descriptors,
                   PRIMARY KEY (set_id, zoom, x, y))

A set is keyed by the extractor engine's file sha256, its input rule (size multiple) and the
photometric normalisation the tiles went through (``[matcher] photometric``): features of another
engine build or another preprocessing are never served. Each tile row holds the blake2b digest
of the encoded tile bytes it was computed from: a tile whose bytes changed is never served stale.
Keypoints are float32 (n, 2) (x, y) in the tile's own px (origin at the centre of its top-left
pixel), scores float32 (n,), descriptors (n, D) float32 or float16 (``descriptor_dtype``).

In flight, :func:`assemble_window` builds a candidate window's features from the stored tiles it
overlaps (shift into window px, drop what the window's eroded border would mask, keep the best
``max_keypoints`` by score): no decode, no extraction. It returns None (the caller extracts)
whenever a stored row is missing or stale, or the window would be resized by the input rule.
"""

from __future__ import annotations

import hashlib
import sqlite3
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from c3_matcher.features import Features
from c3_matcher.tilestore.geo import TILE_PX

__all__ = [
    "FEATURES_SUFFIX",
    "FeatureRequest",
    "FeatureSet",
    "TileFeatureStore",
    "TileFeatures",
    "assemble_window",
    "sidecar_path",
    "tile_digest",
]

FEATURES_SUFFIX = ".features.sqlite"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS feature_sets (
    set_id TEXT PRIMARY KEY, extractor_sha256 TEXT NOT NULL, multiple INTEGER NOT NULL,
    margin_px INTEGER NOT NULL, descriptor_dim INTEGER NOT NULL, descriptor_dtype TEXT NOT NULL,
    strategy TEXT NOT NULL, complete INTEGER NOT NULL DEFAULT 0, tiles INTEGER NOT NULL DEFAULT 0,
    created TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS tile_features (
    set_id TEXT NOT NULL, zoom INTEGER NOT NULL, x INTEGER NOT NULL, y INTEGER NOT NULL,
    tile_digest TEXT NOT NULL, n INTEGER NOT NULL, keypoints BLOB NOT NULL,
    scores BLOB NOT NULL, descriptors BLOB NOT NULL,
    PRIMARY KEY (set_id, zoom, x, y)) WITHOUT ROWID;
"""


def sidecar_path(store_path: str | Path) -> Path:
    """``<store>.features.sqlite`` beside the tile store."""
    p = Path(store_path)
    return p.with_name(p.name + FEATURES_SUFFIX)


def tile_digest(blob: bytes | memoryview) -> str:
    """blake2b (16 bytes, hex) of a tile's encoded bytes."""
    return hashlib.blake2b(blob, digest_size=16).hexdigest()


def set_id_for(extractor_sha256: str, multiple: int, photometric: str = "none") -> str:
    """A feature set's key: the extractor engine, its size multiple and the photometric
    normalisation the tiles were extracted under (``[matcher] photometric``)."""
    base = f"{extractor_sha256}:hw{int(multiple)}"
    return base if photometric == "none" else f"{base}:{photometric}"


@dataclass(frozen=True, slots=True)
class FeatureRequest:
    """What the flight read path asks for: the extractor engine (file sha256) and its input rule
    (``multiple``, ``max_long_side``), the keypoint budget, the valid-mask erosion (px) that
    the extraction path would apply at the window's border, and the photometric normalisation
    of the flight's preprocessing (part of the set's key)."""

    extractor_sha256: str
    multiple: int
    max_long_side: int
    max_keypoints: int
    border_erode_px: int = 4
    photometric: str = "none"

    @property
    def set_id(self) -> str:
        return set_id_for(self.extractor_sha256, self.multiple, self.photometric)


@dataclass(frozen=True, slots=True)
class FeatureSet:
    set_id: str
    extractor_sha256: str
    multiple: int
    margin_px: int
    descriptor_dim: int
    descriptor_dtype: str
    strategy: str
    complete: bool
    tiles: int


@dataclass(frozen=True, slots=True)
class TileFeatures:
    """One tile's stored features (tile px) and the digest of the bytes they came from."""

    tile_digest: str
    keypoints: NDArray[np.float32]
    scores: NDArray[np.float32]
    descriptors: NDArray[Any]


class TileFeatureStore:
    """The sidecar database (read-only by default; ``writable=True`` for the ground command)."""

    def __init__(self, path: str | Path, *, writable: bool = False) -> None:
        self.path = Path(path)
        if writable:
            self._db = sqlite3.connect(str(self.path), timeout=60)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.executescript(_SCHEMA)
            self._db.commit()
        else:
            self._db = sqlite3.connect(f"file:{self.path.resolve()}?mode=ro", uri=True)
        self._sets: dict[str, FeatureSet | None] = {}

    # -- reading ------------------------------------------------------------------------
    def feature_set(self, set_id: str) -> FeatureSet | None:
        if set_id not in self._sets:
            row = self._db.execute(
                "SELECT set_id, extractor_sha256, multiple, margin_px, descriptor_dim, "
                "descriptor_dtype, strategy, complete, tiles FROM feature_sets WHERE set_id=?",
                (set_id,),
            ).fetchone()
            self._sets[set_id] = (
                None
                if row is None
                else FeatureSet(
                    str(row[0]),
                    str(row[1]),
                    int(row[2]),
                    int(row[3]),
                    int(row[4]),
                    str(row[5]),
                    str(row[6]),
                    bool(row[7]),
                    int(row[8]),
                )
            )
        return self._sets[set_id]

    def feature_sets(self) -> list[FeatureSet]:
        ids = [str(r[0]) for r in self._db.execute("SELECT set_id FROM feature_sets ORDER BY 1")]
        self._sets.clear()
        return [s for s in (self.feature_set(i) for i in ids) if s is not None]

    def tile(self, fset: FeatureSet, zoom: int, x: int, y: int) -> TileFeatures | None:
        row = self._db.execute(
            "SELECT tile_digest, n, keypoints, scores, descriptors FROM tile_features "
            "WHERE set_id=? AND zoom=? AND x=? AND y=?",
            (fset.set_id, zoom, x, y),
        ).fetchone()
        if row is None:
            return None
        n = int(row[1])
        dtype = np.float16 if fset.descriptor_dtype == "float16" else np.float32
        return TileFeatures(
            str(row[0]),
            np.frombuffer(row[2], dtype=np.float32).reshape(n, 2),
            np.frombuffer(row[3], dtype=np.float32).reshape(n),
            np.frombuffer(row[4], dtype=dtype).reshape(n, fset.descriptor_dim),
        )

    def done_tiles(self, set_id: str) -> dict[tuple[int, int, int], str]:
        """(zoom, x, y) -> tile digest of every tile stored in a set."""
        return {
            (int(z), int(x), int(y)): str(d)
            for z, x, y, d in self._db.execute(
                "SELECT zoom, x, y, tile_digest FROM tile_features WHERE set_id=?", (set_id,)
            )
        }

    # -- writing (ground) ---------------------------------------------------------------
    def ensure_set(self, fset: FeatureSet) -> None:
        self._db.execute(
            "INSERT OR IGNORE INTO feature_sets (set_id, extractor_sha256, multiple, margin_px, "
            "descriptor_dim, descriptor_dtype, strategy, complete, tiles, created) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, 0, 0, ?)",
            (
                fset.set_id,
                fset.extractor_sha256,
                fset.multiple,
                fset.margin_px,
                fset.descriptor_dim,
                fset.descriptor_dtype,
                fset.strategy,
                time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            ),
        )
        self._db.commit()
        self._sets.pop(fset.set_id, None)

    def put_tiles(self, set_id: str, rows: Iterable[tuple[int, int, int, TileFeatures]]) -> None:
        self._db.executemany(
            "INSERT OR REPLACE INTO tile_features VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [
                (
                    set_id,
                    z,
                    x,
                    y,
                    t.tile_digest,
                    int(t.keypoints.shape[0]),
                    np.ascontiguousarray(t.keypoints, np.float32).tobytes(),
                    np.ascontiguousarray(t.scores, np.float32).tobytes(),
                    np.ascontiguousarray(t.descriptors).tobytes(),
                )
                for z, x, y, t in rows
            ],
        )
        self._db.commit()

    def mark(self, set_id: str, *, complete: bool, tiles: int) -> None:
        self._db.execute(
            "UPDATE feature_sets SET complete=?, tiles=? WHERE set_id=?",
            (int(complete), int(tiles), set_id),
        )
        self._db.commit()
        self._sets.pop(set_id, None)

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> TileFeatureStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class FeatureSource(Protocol):
    """A slippy tile store that may serve stored features (``feature_store`` returns None when
    it has none)."""

    def tile_bytes(self, zoom: int, x: int, y: int) -> memoryview | None: ...

    def feature_store(self) -> TileFeatureStore | None: ...


def assemble_window(
    source: FeatureSource,
    request: FeatureRequest,
    zoom: int,
    origin: tuple[int, int],
    size: tuple[int, int],
) -> Features | None:
    """The features of the (w, h) = ``size`` window of WORLD px whose top-left pixel index is
    ``origin``, assembled from stored tiles, in window px; None when they cannot be served
    exactly as the extraction path would see the window (no store or set, a tile without a row
    or with a stale one, a window the input rule would resize or pad)."""
    w, h = int(size[0]), int(size[1])
    if w > request.max_long_side or h > request.max_long_side:
        return None
    if w % request.multiple or h % request.multiple:
        return None
    store = source.feature_store()
    if store is None:
        return None
    fset = store.feature_set(request.set_id)
    if fset is None:
        return None
    x0, y0 = int(origin[0]), int(origin[1])
    n = 1 << zoom
    e = int(request.border_erode_px)
    kps: list[NDArray[np.float32]] = []
    scs: list[NDArray[np.float32]] = []
    dss: list[NDArray[Any]] = []
    found = 0
    for ty in range(y0 // TILE_PX, (y0 + h - 1) // TILE_PX + 1):
        for tx in range(x0 // TILE_PX, (x0 + w - 1) // TILE_PX + 1):
            if not 0 <= ty < n:
                continue
            blob = source.tile_bytes(zoom, tx % n, ty)
            if blob is None:
                continue  # nodata: no features, as the extraction path masks it
            stored = store.tile(fset, zoom, tx % n, ty)
            if stored is None or stored.tile_digest != tile_digest(blob):
                return None
            found += 1
            kp = stored.keypoints + np.array(
                [tx * TILE_PX - x0, ty * TILE_PX - y0], dtype=np.float32
            )
            r = np.rint(kp)
            keep = (r[:, 0] >= e) & (r[:, 0] <= w - 1 - e) & (r[:, 1] >= e) & (r[:, 1] <= h - 1 - e)
            kps.append(kp[keep])
            scs.append(stored.scores[keep])
            dss.append(stored.descriptors[keep])
    if found == 0:
        return None
    keypoints = np.concatenate(kps).astype(np.float32, copy=False)
    scores = np.concatenate(scs).astype(np.float32, copy=False)
    descriptors = np.concatenate(dss)
    order = np.argsort(-scores, kind="stable")[: request.max_keypoints]
    return Features(
        keypoints=np.ascontiguousarray(keypoints[order]),
        descriptors=np.ascontiguousarray(descriptors[order], dtype=np.float32),
        keypoint_scores=np.ascontiguousarray(scores[order]),
        image_size=(w, h),
    )


def stored_sets(store: TileFeatureStore) -> Iterator[Mapping[str, Any]]:
    """The sets of a sidecar as dicts (for ``features info``)."""
    for s in store.feature_sets():
        yield {
            "set_id": s.set_id,
            "strategy": s.strategy,
            "margin_px": s.margin_px,
            "descriptor_dim": s.descriptor_dim,
            "descriptor_dtype": s.descriptor_dtype,
            "complete": s.complete,
            "tiles": s.tiles,
        }
