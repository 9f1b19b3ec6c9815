"""Image sizes read from their headers, never decoded: (width, height) of a PNG, JPEG, TIFF, BMP
or WebP from its first bytes (:func:`image_header_size`), or from a file (:func:`image_file_size`,
a TIFF's first IFD wherever it lies), so that an image above a pixel limit is refused before its
decoder allocates anything (:func:`c3_matcher.tiles.decode_image`)."""

from __future__ import annotations

import struct
from typing import BinaryIO

from c3_matcher.image_tags import displayed_size, exif_orientation

__all__ = [
    "TIFF_MAGIC",
    "RepeatedTiffTagError",
    "image_file_size",
    "image_header_size",
    "stated_size",
]

TIFF_MAGIC = (b"II*\x00", b"MM\x00*")
"""The first four bytes of a TIFF: little-endian, big-endian."""


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
    as its width, as :func:`~c3_matcher.tiles.decode_image` returns it."""
    try:
        size = stated_size(head)
    except RepeatedTiffTagError:
        return None
    return None if size is None else displayed_size(size, exif_orientation(head))


def stated_size(head: bytes | memoryview) -> tuple[int, int] | None:
    """:func:`image_header_size`, raising :class:`RepeatedTiffTagError` where that says None."""
    try:
        if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
            w, h = struct.unpack(">II", head[16:24])
            return int(w), int(h)
        if head[:2] == b"\xff\xd8":
            return _jpeg_size(head)
        if head[:4] in TIFF_MAGIC:
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
    if size is not None or head[:4] not in TIFF_MAGIC:
        return size
    try:
        (offset,) = struct.unpack(_tiff_endian(head) + "I", head[4:8])
        fh.seek(offset)
        (count,) = struct.unpack(_tiff_endian(head) + "H", fh.read(2))
        return _tiff_size(head[:8] + fh.read(12 * count), count)
    except (struct.error, OSError, ValueError):
        return None


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
