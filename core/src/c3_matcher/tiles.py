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
is a value each reader is given, never process state (``read_image``, the handles).
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path
from typing import BinaryIO

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.errors import InvalidInputError
from c3_matcher.file_kinds import kind_of
from c3_matcher.image_tags import (
    apply_orientation,
    declared_top,
    displayed_size,
    exif_orientation,
    sixteen_bit_top,
    tiff_orientation,
)

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
    if as_displayed and raw.data[:4] in _TIFF_MAGIC and tiff_orientation(raw.data) >= 5:
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


class RepeatedTiffTagError(ValueError):
    """A TIFF whose first IFD gives its width or height more than once: which one the decoder
    believes is its own choice (libtiff keeps the first), so no size read from it is."""


def image_header_size(head: bytes | memoryview) -> tuple[int, int] | None:
    """(width, height) from the first bytes of a PNG, JPEG, TIFF, BMP or WebP file, or None
    when the format or its header is not recognised (a GIF too: OpenCV does not decode it) or
    cannot be believed (a TIFF giving its width or height twice: :class:`RepeatedTiffTagError`).
    A TIFF's first IFD must lie within ``head`` (libtiff and OpenCV write it after the pixels:
    :func:`image_file_size` reads it where it is). The size is the image's as displayed: a
    JPEG, PNG or WebP whose EXIF Orientation turns it a quarter (5-8) gives its stored height
    as its width, as :func:`decode_image` returns it."""
    try:
        size = _header_size(head)
    except RepeatedTiffTagError:
        return None
    return None if size is None else displayed_size(size, exif_orientation(head))


def _header_size(head: bytes | memoryview) -> tuple[int, int] | None:
    """:func:`image_header_size`, raising :class:`RepeatedTiffTagError` where that says None."""
    try:
        if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
            w, h = struct.unpack(">II", head[16:24])
            return int(w), int(h)
        if head[:2] == b"\xff\xd8":
            return _jpeg_size(head)
        if head[:4] in _TIFF_MAGIC:
            return _tiff_size(head)
        if head[:2] == b"BM":
            w, h = struct.unpack("<ii", head[18:26])
            return abs(int(w)), abs(int(h))
        if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
            chunk = head[12:16]
            if chunk == b"VP8X":
                w = int.from_bytes(head[24:27], "little") + 1
                h = int.from_bytes(head[27:30], "little") + 1
                return w, h
            if chunk == b"VP8L":
                bits = int.from_bytes(head[21:25], "little")
                return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
            if chunk == b"VP8 ":
                w, h = struct.unpack("<HH", head[26:30])
                return int(w & 0x3FFF), int(h & 0x3FFF)
    except struct.error:
        return None
    return None


def _jpeg_size(head: bytes | memoryview) -> tuple[int, int] | None:
    i = 2
    while i + 9 < len(head):
        if head[i] != 0xFF:
            return None
        marker = head[i + 1]
        if marker == 0xFF:
            i += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            i += 2
            continue
        (length,) = struct.unpack(">H", head[i + 2 : i + 4])
        if marker in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF):
            h, w = struct.unpack(">HH", head[i + 5 : i + 9])
            return int(w), int(h)
        i += 2 + length
    return None


def image_file_size(fh: BinaryIO) -> tuple[int, int] | None:
    """:func:`image_header_size` of the file open in ``fh`` (binary, seekable) from its first
    MiB, and from its first IFD where a TIFF's lies beyond that."""
    head = fh.read(1 << 20)
    size = image_header_size(head)
    if size is not None or head[:4] not in _TIFF_MAGIC:
        return size
    try:
        (offset,) = struct.unpack(_tiff_endian(head) + "I", head[4:8])
        fh.seek(offset)
        (count,) = struct.unpack(_tiff_endian(head) + "H", fh.read(2))
        return _tiff_size(head[:8] + fh.read(12 * count), count)
    except (struct.error, OSError, ValueError):
        return None


_TIFF_MAGIC = (b"II*\x00", b"MM\x00*")


def _tiff_endian(head: bytes | memoryview) -> str:
    return "<" if head[:2] == b"II" else ">"


def _tiff_size(head: bytes | memoryview, count: int | None = None) -> tuple[int, int] | None:
    """A TIFF's size from its first IFD: at its offset in ``head``, or (``count`` given) its
    ``count`` entries right after ``head``'s first 8 bytes."""
    endian = _tiff_endian(head)
    if count is None:
        (offset,) = struct.unpack(endian + "I", head[4:8])
        (count,) = struct.unpack(endian + "H", head[offset : offset + 2])
    else:
        offset = 6  # the entries follow the 8-byte header directly
    dims: dict[int, int] = {}
    for k in range(count):
        entry = head[offset + 2 + 12 * k : offset + 14 + 12 * k]
        tag, typ = struct.unpack(endian + "HH", entry[:4])
        if tag in (256, 257):
            if tag in dims:
                name = "width" if tag == 256 else "height"
                raise RepeatedTiffTagError(
                    f"a TIFF whose first IFD gives its {name} (tag {tag}) twice: its size "
                    "cannot be believed, refused before decoding"
                )
            value = struct.unpack(
                endian + ("H" if typ == 3 else "I"), entry[8 : 10 if typ == 3 else 12]
            )
            dims[tag] = int(value[0])
    if 256 in dims and 257 in dims:
        return dims[256], dims[257]
    return None


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


class MmapTileHandle:
    """A tile image file; ``encoded()`` reads it (from the page cache) under a size check.

    The name is kept for compatibility: no mapping is held (see the module docstring), so a file
    that shrinks or vanishes after the handle was made is an ``InvalidInputError`` of this
    candidate, never a SIGBUS of the process.
    """

    def __init__(self, path: Path, *, max_pixels: int = DEFAULT_MAX_IMAGE_PIXELS) -> None:
        self._path = Path(path)
        self._max_pixels = _checked_limit(max_pixels)
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
            fd = os.open(self._path, os.O_RDONLY)
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
        return decode_image(self.encoded(), str(self._path), self._max_pixels)

    def __repr__(self) -> str:
        return f"MmapTileHandle({str(self._path)!r})"


class BytesTileHandle:
    """A tile held as bytes in memory (tests, tiles received over a bus)."""

    def __init__(
        self, data: bytes, name: str = "<bytes>", *, max_pixels: int = DEFAULT_MAX_IMAGE_PIXELS
    ) -> None:
        self._data = data
        self._name = name
        self._max_pixels = _checked_limit(max_pixels)

    def encoded(self) -> memoryview:
        return memoryview(self._data)

    def decode(self) -> NDArray[np.uint8]:
        return decode_image(self.encoded(), self._name, self._max_pixels)

    def __repr__(self) -> str:
        return f"BytesTileHandle({self._name!r}, {len(self._data)} bytes)"
