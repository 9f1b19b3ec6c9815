"""Tile pixel handles (C6 side): references to encoded tile bytes that decode on demand.

``MmapTileHandle`` maps an image file read-only: the bytes stay in the page cache and nothing is
copied into the process until ``decode()`` (AZ-345 constraint: the handle is page-cache backed,
decode is per call).
"""

from __future__ import annotations

import mmap
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.errors import InvalidInputError

__all__ = ["BytesTileHandle", "ImageDecodeError", "MmapTileHandle", "decode_image", "read_image"]


class ImageDecodeError(InvalidInputError):
    """Encoded image bytes could not be decoded."""


def decode_image(buffer: memoryview | bytes, what: str) -> NDArray[np.uint8]:
    """Decode PNG/JPEG/TIFF/... bytes to uint8 RGB (H, W, 3); 16-bit is scaled, alpha dropped,
    4-band (e.g. R,G,B,NIR GeoTIFF) keeps its first three bands in file order."""
    raw = np.frombuffer(buffer, dtype=np.uint8)
    if raw.size == 0:
        raise ImageDecodeError(what, "no bytes to decode")
    image = cv2.imdecode(raw, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ImageDecodeError(what, "not a decodable image (PNG, JPEG, TIFF, ...)")
    return to_rgb8(image, what, bgr=True)


def to_rgb8(image: NDArray[np.generic], what: str, *, bgr: bool) -> NDArray[np.uint8]:
    """Normalise an OpenCV-decoded array to uint8 RGB."""
    if image.dtype == np.uint16:
        image = (image // 257).astype(np.uint8)
    elif image.dtype != np.uint8:
        raise ImageDecodeError(what, f"unsupported pixel type {image.dtype}")
    if image.ndim == 2:
        return np.ascontiguousarray(np.repeat(image[:, :, None], 3, axis=2))
    channels = image.shape[2]
    if channels == 1:
        return np.ascontiguousarray(np.repeat(image, 3, axis=2))
    if channels == 4 and bgr:
        # OpenCV returns BGRA for PNG with alpha but B,G,R,NIR-as-4th for 4-band TIFF: both keep
        # the first three channels as colour.
        image = image[:, :, :3]
    elif channels > 3:
        image = image[:, :, :3]
    rgb = image[:, :, ::-1] if bgr else image
    return np.ascontiguousarray(rgb, dtype=np.uint8)


def read_image(path: Path) -> NDArray[np.uint8]:
    """Read an image file to uint8 RGB, naming the file when it is missing or undecodable."""
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(str(p), "no such image file")
    return MmapTileHandle(p).decode()


class MmapTileHandle:
    """A tile image file mapped read-only; ``encoded()`` is a zero-copy view of the mapping."""

    def __init__(self, path: Path) -> None:
        self._path = Path(path)
        try:
            with self._path.open("rb") as fh:
                self._map = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        except (OSError, ValueError) as exc:  # ValueError: empty file cannot be mapped
            raise InvalidInputError(str(self._path), f"cannot map tile file: {exc}") from exc

    @property
    def path(self) -> Path:
        return self._path

    def encoded(self) -> memoryview:
        return memoryview(self._map)

    def decode(self) -> NDArray[np.uint8]:
        return decode_image(self.encoded(), str(self._path))

    def __repr__(self) -> str:
        return f"MmapTileHandle({str(self._path)!r})"


class BytesTileHandle:
    """A tile held as bytes in memory (tests, tiles received over a bus)."""

    def __init__(self, data: bytes, name: str = "<bytes>") -> None:
        self._data = data
        self._name = name

    def encoded(self) -> memoryview:
        return memoryview(self._data)

    def decode(self) -> NDArray[np.uint8]:
        return decode_image(self.encoded(), self._name)

    def __repr__(self) -> str:
        return f"BytesTileHandle({self._name!r}, {len(self._data)} bytes)"
