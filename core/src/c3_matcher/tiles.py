"""Tile pixel handles (C6 side): references to encoded tile bytes that decode on demand.

``MmapTileHandle`` references an image file: its bytes stay in the page cache and are read
into the process (``pread`` under a size check) only by ``encoded()`` / ``decode()``
(constraint: page-cache backed, decode per call). It deliberately does NOT keep an ``mmap``
of the file: touching a mapping whose file shrank kills the process with SIGBUS, whereas a
read of a shrunk file is that candidate's error.

Decompression bombs: ``decode_image`` reads the image header (PNG, JPEG, TIFF, BMP, WebP)
and refuses an image above its ``max_pixels`` argument (width x height; the configured
``[matcher] max_image_pixels`` where the caller has a configuration, else
``DEFAULT_MAX_IMAGE_PIXELS``, 50 Mpx) before decoding it; an image whose size cannot be read
from its header is refused too, and so is a PNG cut short (its chunks end before IEND: libpng,
given one, writes its own line to the process's stderr), and a TIFF whose first IFD gives its
width or height twice (libtiff believes the first, a reader keeping the last would check a
size never decoded). The decoded image's size is checked against the limit too, for any header
read otherwise than its decoder reads it: that check costs nothing, but comes after the
decoder's allocation (bounded then only by OpenCV's own limit, ``OPENCV_IO_MAX_IMAGE_PIXELS``,
2^30 px by default), so it keeps such an image from the matcher, not from memory. The limit
is a value each reader is given, never process state (``read_image``, the handles): a composed
matcher gives its own to each candidate's handle, ``decode_within(limit)``
(:mod:`c3_matcher.tile_limit`). Header parsing lives in :mod:`c3_matcher.image_headers`.
"""

from __future__ import annotations

import os
import zlib
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.errors import InvalidInputError
from c3_matcher.file_kinds import kind_of
from c3_matcher.image_headers import (
    TIFF_MAGIC,
    RepeatedTiffTagError,
    image_file_size,
    image_header_size,
)
from c3_matcher.image_headers import stated_size as _header_size
from c3_matcher.image_tags import (
    apply_orientation,
    declared_top,
    exif_orientation,
    sixteen_bit_top,
    tiff_orientation,
)
from c3_matcher.regular_files import open_regular

__all__ = [
    "DEFAULT_MAX_IMAGE_PIXELS",
    "BytesTileHandle",
    "ImageDecodeError",
    "MmapTileHandle",
    "decode_image",
    "image_file_size",
    "image_header_size",
    "read_image",
]

DEFAULT_MAX_IMAGE_PIXELS = 50_000_000  # the default of [matcher] max_image_pixels
DECODABLE_FORMATS = "PNG, JPEG, TIFF, BMP, WebP"
"""The image formats read (by their header, then by OpenCV), as messages name them."""


def _checked_limit(value: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 256:
        raise InvalidInputError("matcher.max_image_pixels", f"must be an int >= 256, got {value!r}")
    return value


class ImageDecodeError(InvalidInputError):
    """Encoded image bytes could not be decoded."""


def decode_image(
    buffer: memoryview | bytes,
    what: str,
    max_pixels: int = DEFAULT_MAX_IMAGE_PIXELS,
    *,
    as_displayed: bool = False,
) -> NDArray[np.uint8]:
    """Decode PNG/JPEG/TIFF/... bytes to uint8 RGB (H, W, 3): a frame ``as_displayed`` (EXIF
    orientation applied, 16-bit scaled by its camera's depth: :mod:`c3_matcher.image_tags`), a
    map tile as stored (its place is its grid's, never turned; 16-bit / 257 for every tile alike:
    no seam within a scene), alpha dropped, 4-band keeps its first 3 bands. An image above
    ``max_pixels`` (width x height, read from its header) is refused before decoding, and one
    that decodes above it all the same is refused after (see the module docstring)."""
    raw = np.frombuffer(buffer, dtype=np.uint8)
    if raw.size == 0:
        raise ImageDecodeError(what, "no bytes to decode")
    try:
        size = _header_size(raw.data)  # the whole buffer: a TIFF's IFD may follow its pixels
    except RepeatedTiffTagError as exc:
        raise ImageDecodeError(what, str(exc)) from None
    if size is None:
        raise ImageDecodeError(what, f"not a decodable image ({DECODABLE_FORMATS})")
    damage = _png_damage(raw)  # refused here: libpng would write its own line to fd 2
    if damage is not None:  # before the header's size is believed
        raise ImageDecodeError(what, damage)
    width, height = size
    limit = _checked_limit(max_pixels)
    if width <= 0 or height <= 0:
        raise ImageDecodeError(what, f"its header declares {width}x{height} px: not an image")
    if width * height > limit:
        raise ImageDecodeError(
            what,
            f"image of {width}x{height} px exceeds the limit of {limit} px "
            "([matcher] max_image_pixels); refused before decoding",
        )
    if as_displayed and raw.data[:4] in TIFF_MAGIC and tiff_orientation(raw.data) >= 5:
        raise ImageDecodeError(
            what,
            f"a TIFF stored turned a quarter (its Orientation tag is {tiff_orientation(raw.data)})"
            ": OpenCV cannot decode it; write it upright (Orientation 1)",
        )
    image = cv2.imdecode(raw, cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ImageDecodeError(what, f"not a decodable image ({DECODABLE_FORMATS})")
    if as_displayed:
        image = apply_orientation(image, exif_orientation(raw.data))
    decoded_h, decoded_w = image.shape[:2]
    if decoded_w * decoded_h > limit:  # a header read otherwise than the decoder reads it
        raise ImageDecodeError(
            what,
            f"decoded to {decoded_w}x{decoded_h} px, above the limit of {limit} px ([matcher] "
            f"max_image_pixels), though its header declares {width}x{height} px",
        )
    declared = declared_top(raw.data) if as_displayed else 65535  # a tile: / 257, as ever
    return to_rgb8(image, what, bgr=True, declared=declared)


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_damage(raw: NDArray[np.uint8]) -> str | None:
    """Why ``raw``, a PNG, would fail in libpng (None: it is whole, or not a PNG): cut short
    (its chunks, followed by their lengths from the signature on, run past its end before the
    IEND chunk; bytes after IEND are allowed, as libpng reads no further), or a critical chunk
    (IHDR, PLTE, IDAT, IEND: a type whose first letter is upper case) failing its CRC, as a
    damaged copy does. libpng, given either, writes its own line ("libpng error: PNG input
    buffer is incomplete", "libpng error: IDAT: CRC error") to the process's stderr (OpenCV's
    JPEG decoder refuses a damaged JPEG silently). An ancillary chunk's CRC is libpng's to
    judge: it skips the chunk and decodes the image. Reads each critical chunk once (about
    0.1 ms for a 500 kB tile)."""
    data = raw.data
    if bytes(data[:8]) != _PNG_SIGNATURE:
        return None
    at, end = 8, len(data)
    while at + 12 <= end:
        length = int.from_bytes(data[at : at + 4], "big")
        chunk_end = at + 8 + length  # its CRC follows
        if chunk_end + 4 > end:
            break
        kind = bytes(data[at + 4 : at + 8])
        crc = int.from_bytes(data[chunk_end : chunk_end + 4], "big")
        if kind[:1].isupper() and zlib.crc32(data[at + 4 : chunk_end]) != crc:
            name = kind.decode("ascii", "replace")
            return f"a damaged PNG: its {name} chunk at byte {at} fails its CRC check"
        if kind == b"IEND":
            return None
        at = chunk_end + 4
    return "a PNG cut short: its chunks end before the IEND chunk"


def to_rgb8(
    image: NDArray[np.generic], what: str, *, bgr: bool, declared: int | None = None
) -> NDArray[np.uint8]:
    """Normalise an OpenCV-decoded array to uint8 RGB. 16-bit samples are scaled so that the
    camera's top value becomes 255 (:func:`~c3_matcher.image_tags.sixteen_bit_top`, given the
    top the file ``declared``): 10- or 12-bit data keeps its grey levels, and an image using the
    whole 16-bit range is divided by 257."""
    if image.dtype == np.uint16:
        top = sixteen_bit_top(image.view(np.uint16), declared)
        if top == 65535:
            image = (image // 257).astype(np.uint8)
        else:  # floor(v * 255 / top), as // 257 is for 65535
            image = np.minimum(image.astype(np.uint32) * 255 // top, 255).astype(np.uint8)
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


def read_image(path: Path, max_pixels: int = DEFAULT_MAX_IMAGE_PIXELS) -> NDArray[np.uint8]:
    """Read an image file to uint8 RGB, naming the file when it is missing, a directory or
    undecodable (or above ``max_pixels``, width x height)."""
    p = Path(path)
    if p.is_dir():
        raise InvalidInputError(str(p), "is a directory, not an image")
    if not p.exists():
        raise InvalidInputError(str(p), "no such image file")
    image = MmapTileHandle(p, max_pixels=max_pixels).encoded()
    return decode_image(image, str(p), max_pixels, as_displayed=True)


def _limit_of(own: int | None, given: int | None) -> int:
    """The pixel limit a handle decodes under: the tighter of its own (``max_pixels`` when it
    was made; None: none) and the one ``given`` to ``decode_within`` (None: ``decode()``),
    ``DEFAULT_MAX_IMAGE_PIXELS`` when neither is."""
    limits = [_checked_limit(v) for v in (own, given) if v is not None]
    return min(limits, default=DEFAULT_MAX_IMAGE_PIXELS)


class MmapTileHandle:
    """A tile image file; ``encoded()`` reads it (from the page cache) under a size check.

    The name is kept for compatibility: no mapping is held (see the module docstring), so a file
    that shrinks or vanishes after the handle was made is an ``InvalidInputError`` of this
    candidate, never a SIGBUS of the process, and one replaced by a FIFO or a device is refused
    when read, never waited on. ``decode()`` decodes within ``max_pixels`` (None: the default,
    50 Mpx), ``decode_within(limit)`` within the tighter of it and ``limit``: a matcher's
    configured ``[matcher] max_image_pixels``.
    """

    def __init__(self, path: Path, *, max_pixels: int | None = None) -> None:
        self._path = Path(path)
        self._max_pixels = None if max_pixels is None else _checked_limit(max_pixels)
        try:
            st = self._path.stat()
        except OSError as exc:
            raise InvalidInputError(str(self._path), f"cannot read image file: {exc}") from exc
        special = kind_of(st.st_mode)
        if special is not None:
            raise InvalidInputError(str(self._path), f"cannot read image file: it is {special}")
        if st.st_size == 0:
            raise InvalidInputError(str(self._path), "cannot read image file: it is empty")

    @property
    def path(self) -> Path:
        return self._path

    def encoded(self) -> memoryview:
        try:
            fd = open_regular(self._path)
        except OSError as exc:
            raise InvalidInputError(str(self._path), f"cannot read image file: {exc}") from exc
        try:
            size = os.fstat(fd).st_size
            if size == 0:
                raise InvalidInputError(str(self._path), "cannot read image file: it is empty")
            buf = bytearray(size)
            view = memoryview(buf)
            got = 0
            while got < size:
                n = os.preadv(fd, [view[got:]], got)
                if n <= 0:
                    raise InvalidInputError(
                        str(self._path), f"image file shrank while reading ({got} of {size} bytes)"
                    )
                got += n
        except OSError as exc:
            raise InvalidInputError(str(self._path), f"cannot read image file: {exc}") from exc
        finally:
            os.close(fd)
        return memoryview(buf).toreadonly()

    def decode(self) -> NDArray[np.uint8]:
        return self.decode_within(None)

    def decode_within(self, max_pixels: int | None) -> NDArray[np.uint8]:
        """``decode()`` refusing an image above ``max_pixels`` too (width x height)."""
        limit = _limit_of(self._max_pixels, max_pixels)
        return decode_image(self.encoded(), str(self._path), limit)

    def __repr__(self) -> str:
        return f"MmapTileHandle({str(self._path)!r})"


class BytesTileHandle:
    """A tile held as bytes in memory (tests, tiles received over a bus); its pixel limits are
    :class:`MmapTileHandle`'s."""

    def __init__(
        self, data: bytes, name: str = "<bytes>", *, max_pixels: int | None = None
    ) -> None:
        self._data = data
        self._name = name
        self._max_pixels = None if max_pixels is None else _checked_limit(max_pixels)

    def encoded(self) -> memoryview:
        return memoryview(self._data)

    def decode(self) -> NDArray[np.uint8]:
        return self.decode_within(None)

    def decode_within(self, max_pixels: int | None) -> NDArray[np.uint8]:
        """``decode()`` refusing an image above ``max_pixels`` too (width x height)."""
        return decode_image(self.encoded(), self._name, _limit_of(self._max_pixels, max_pixels))

    def __repr__(self) -> str:
        return f"BytesTileHandle({self._name!r}, {len(self._data)} bytes)"
