"""Stored-feature windows: their grid, their keys and digests, and the records a sidecar holds.

A window is a square of WORLD px whose top-left pixel is a multiple of the set's ``stride_px``;
keypoints are float32 (n, 2) (x, y) in window px (origin at the centre of its top-left pixel).
The format and what each key depends on: :mod:`c3_matcher.tilestore.features`.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, fields
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from c3_matcher.engines.providers import CPU_PROVIDER
from c3_matcher.tilestore.geo import TILE_PX


def tile_digest(blob: bytes | memoryview) -> str:
    """sha256 (hex) of a tile's encoded bytes (as a tile store's ``c3_tile_digest`` table)."""
    return hashlib.sha256(blob).hexdigest()


class _TileBytes(Protocol):
    def tile_bytes(self, zoom: int, x: int, y: int) -> memoryview | bytes | None: ...


def stored_tile_digest(source: _TileBytes, key: tuple[int, int, int]) -> str | None:
    """The digest of stored tile ``key`` (zoom, x, y) of ``source``: its bytes' sha256 (the
    flight's, the build's and ``--verify``'s), None (``-`` in a window's digest) for a missing
    tile or one stored with NULL data."""
    blob = source.tile_bytes(*key)
    return None if blob is None else tile_digest(blob)


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
    upscale: int = 1,
) -> str:
    """A window set's key: everything a window's extraction depends on (module docstring);
    ``upscale`` (the input rule's: the extractor ran on each window enlarged that many times)
    is in it when it is not 1, so sets built before it existed keep their keys."""
    scaled = "" if upscale == 1 else f":x{int(upscale)}"
    return (
        f"{extractor_sha256}:{provider}:hw{int(multiple)}:{photometric}:"
        f"e{int(border_erode_px)}:w{int(window_px)}{scaled}"
    )


@dataclass(frozen=True, slots=True)
class FeatureRequest:
    """What the flight read path asks for: the extractor engine (file sha256) and the execution
    provider it runs on, its input rule (``multiple``, ``max_long_side``, ``upscale``), the
    keypoint budget, the valid-mask erosion (px) and the photometric normalisation of the
    flight's preprocessing."""

    extractor_sha256: str
    multiple: int
    max_long_side: int
    max_keypoints: int
    border_erode_px: int = 4
    photometric: str = "none"
    provider: str = CPU_PROVIDER
    upscale: int = 1

    def set_id(self, window_px: int) -> str:
        """The key of the set holding ``window_px`` windows for this request."""
        return set_id_for(
            self.extractor_sha256,
            self.provider,
            self.multiple,
            self.photometric,
            self.border_erode_px,
            window_px,
            self.upscale,
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

    @classmethod
    def of_row(cls, row: Sequence[Any]) -> FeatureSet:
        """The set a stored row holds (its fields, in order), every value checked: ValueError
        naming the first one of another type than its field's, or out of its range (SQLite
        keeps any value in any column)."""
        values: list[Any] = []
        for f, v in zip(fields(cls), row, strict=True):
            why = _malformed(f.name, str(f.type), v)
            if why is not None:
                raise ValueError(f"{f.name} {repr(v)[:40]} {why}")
            values.append(bool(v) if f.type == "bool" else v)
        return cls(*values)


_MAY_BE_ZERO = ("border_erode_px", "windows")  # the set's counts that may be 0 (others >= 1)


def _malformed(name: str, kind: str, value: object) -> str | None:
    """Why the stored ``value`` of the FeatureSet field ``name`` (annotated ``kind``) is not
    one, or None."""
    if kind == "str":
        if type(value) is not str:
            return "is not a text"
        if name == "descriptor_dtype":
            try:
                np.dtype(value)
            except TypeError:
                return "is not a NumPy dtype"
        return None
    if type(value) is not int:
        return "is not an integer"
    if kind == "bool":
        return None if value in (0, 1) else "is not 0 or 1"
    least = 0 if name in _MAY_BE_ZERO else 1
    return None if value >= least else f"is not >= {least}"


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


def grid_index(origin: tuple[int, int], stride_px: int) -> tuple[int, int]:
    """The grid window nearest to a window whose top-left pixel is ``origin`` (WORLD px): the
    (gx, gy) with (gx, gy) * ``stride_px`` closest to it (halves round up)."""
    return (
        math.floor(origin[0] / stride_px + 0.5),
        math.floor(origin[1] / stride_px + 0.5),
    )


def decode_row(
    fset: FeatureSet, key: tuple[str, int, int, int], row: Sequence[Any]
) -> WindowFeatures:
    """The window a ``window_features`` row (``window_digest, n, keypoints, scores,
    descriptors, checksum``) of ``fset`` holds under ``key`` (set, zoom, gx, gy), verified: a
    ValueError saying why it is refused (``checksum mismatch``, ``undecodable (...)``)."""
    try:
        n, d = int(row[1]), fset.descriptor_dim
        if n < 0:
            raise ValueError(f"negative count {n}")
        ok = row_checksum(key, str(row[0]), n, row[2:5]) == str(row[5])
        stored = WindowFeatures(
            str(row[0]),
            np.frombuffer(row[2], dtype=np.float32).reshape(n, 2),
            np.frombuffer(row[3], dtype=np.float32).reshape(n),
            np.frombuffer(row[4], dtype=np.dtype(fset.descriptor_dtype)).reshape(n, d),
        )
    except (ValueError, TypeError) as exc:
        raise ValueError(f"undecodable ({exc})") from None
    if not ok:
        raise ValueError("checksum mismatch")
    return stored
