"""What an encoded image says about its own pixels, beyond their size: the EXIF orientation it
is to be shown in, and how many bits of its 16-bit samples are significant.

Orientation: a camera that stores its pixels turned writes the EXIF Orientation tag (2-8) so
that every viewer, and ``cv2.imread``'s default, shows the image upright. The matcher applies it
too (:func:`apply_orientation`, JPEG APP1, PNG ``eXIf`` and WebP ``EXIF``): a frame is the image
as displayed, and its calibration describes that image, as a calibration made from
``cv2.imread`` frames or read off a viewer does. Refusing the tag instead would refuse every
frame of a camera held turned, for no safer result: a calibration of the stored pixels of a
frame turned a quarter is still refused by its size. A TIFF's own Orientation tag is libtiff's:
OpenCV shows values 2-4 upright itself and cannot decode 5-8 (refused naming the tag).
Values outside 1-8 mean nothing: the image is used as stored, as viewers show it.

Depth: cameras write 10-, 12- or 14-bit samples (Mono10, Mono12) in the low bits of 16-bit
PNG or TIFF words, so dividing by 257 leaves such a frame 4 or 16 grey levels.
:func:`sixteen_bit_top` gives the value that becomes 255: the top the file declares (PNG
``sBIT``, TIFF ``MaxSampleValue``) when its pixels fit in it, else the top of the smallest of
10, 12, 14 or 16 bits holding the frame's largest sample. A declared depth is the camera's; an
inferred one is each frame's: every frame of a 12-bit camera whose brightest pixel passes a
quarter of its range gets the same scale, but a darker frame (or a full-range camera's frame
at dusk) is read at a smaller depth, brighter, never with fewer grey levels: the matchers are
indifferent to a frame's gain (one lamp pixel moving a dark frame's scale 4x changed no match
measured: 1173, 1178, 1175 inliers). An image using the 16-bit range is divided by 257 as
before. A PNG ``sBIT`` whose pixels exceed it is a PNG scaled to the full range, as the PNG
specification writes one: it is read by its values. Map tiles are read as stored, none of
this (``tiles.decode_image``). A tag whose count the file cannot hold is no tag.
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "apply_orientation",
    "declared_top",
    "displayed_size",
    "exif_orientation",
    "sixteen_bit_top",
    "tiff_orientation",
]

_ORIENTATION_TAG = 274
_MAX_SAMPLE_VALUE_TAG = 281
_DEPTHS = (10, 12, 14, 16)


def _ifd0(tiff: bytes | memoryview) -> dict[int, tuple[int, int, bytes]]:
    """Tag -> (type, count, its 4-byte value field) of the first IFD of TIFF-structured bytes
    (a TIFF file or an EXIF block); empty when they are not one."""
    head = bytes(tiff[:4])
    if head not in (b"II*\x00", b"MM\x00*"):
        return {}
    endian = "<" if head[:2] == b"II" else ">"
    (offset,) = struct.unpack(endian + "I", tiff[4:8])
    (count,) = struct.unpack(endian + "H", tiff[offset : offset + 2])
    entries: dict[int, tuple[int, int, bytes]] = {}
    for k in range(count):
        entry = bytes(tiff[offset + 2 + 12 * k : offset + 14 + 12 * k])
        tag, typ, n = struct.unpack(endian + "HHI", entry[:8])
        entries.setdefault(tag, (typ, n, entry[8:12]))
    return entries


def _shorts(tiff: bytes | memoryview, field: tuple[int, int, bytes]) -> list[int]:
    """The SHORT (or LONG) values of an IFD entry: in its value field, or at its offset."""
    typ, n, value = field
    endian = "<" if bytes(tiff[:2]) == b"II" else ">"
    size = 2 if typ == 3 else 4 if typ == 4 else 0
    if size == 0 or n == 0 or n * size > len(tiff):  # a count the file cannot hold: damaged
        return []
    data = (
        value[: n * size]
        if n * size <= 4
        else tiff[struct.unpack(endian + "I", value)[0] :][: n * size]
    )
    return list(struct.unpack(f"{endian}{n}{'H' if size == 2 else 'I'}", bytes(data)))


def _tag_value(tiff: bytes | memoryview, tag: int) -> list[int]:
    try:
        field = _ifd0(tiff).get(tag)
        return [] if field is None else _shorts(tiff, field)
    except (struct.error, ValueError):
        return []


def _jpeg_exif(data: memoryview) -> memoryview | None:
    """The TIFF-structured EXIF block of a JPEG's APP1 segment, or None."""
    i = 2
    while i + 4 <= len(data) and data[i] == 0xFF:
        marker = data[i + 1]
        if marker in (0xDA, 0xD9) or (0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC)):
            return None  # the scan or a frame header: EXIF comes before both
        (length,) = struct.unpack(">H", data[i + 2 : i + 4])
        if marker == 0xE1 and bytes(data[i + 4 : i + 10]) == b"Exif\x00\x00":
            return data[i + 10 : i + 2 + length]
        i += 2 + length
    return None


def _chunks(data: memoryview, at: int, big: bool) -> dict[bytes, memoryview]:
    """The first chunk of each type of a PNG (``big``: big-endian lengths before the type) or
    a RIFF (type then little-endian length, padded to even) from byte ``at``, up to the pixels."""
    found: dict[bytes, memoryview] = {}
    while at + 8 <= len(data):
        if big:
            length, kind = int.from_bytes(data[at : at + 4], "big"), bytes(data[at + 4 : at + 8])
        else:
            kind, length = bytes(data[at : at + 4]), int.from_bytes(data[at + 4 : at + 8], "little")
        if kind in (b"IDAT", b"IEND"):
            break
        found.setdefault(kind, data[at + 8 : at + 8 + length])
        at += 8 + length + (4 if big else length % 2)
    return found


def _exif_block(data: memoryview) -> memoryview | None:
    if bytes(data[:2]) == b"\xff\xd8":
        return _jpeg_exif(data)
    if bytes(data[:8]) == b"\x89PNG\r\n\x1a\n":
        return _chunks(data, 8, big=True).get(b"eXIf")
    if bytes(data[:4]) == b"RIFF" and bytes(data[8:12]) == b"WEBP":
        block = _chunks(data, 12, big=False).get(b"EXIF")
        if block is not None and bytes(block[:6]) == b"Exif\x00\x00":
            block = block[6:]  # some writers keep JPEG's prefix
        return block
    return None


def exif_orientation(data: bytes | memoryview) -> int:
    """The EXIF Orientation (2-8) of an encoded JPEG, PNG or WebP image; 1 without one, with a
    value outside 2-8, or with an EXIF block that cannot be read (viewers show those as
    stored)."""
    try:
        block = _exif_block(memoryview(data))
    except (struct.error, ValueError):
        return 1
    values = [] if block is None else _tag_value(block, _ORIENTATION_TAG)
    return values[0] if values and 2 <= values[0] <= 8 else 1


def tiff_orientation(data: bytes | memoryview) -> int:
    """A TIFF file's own Orientation tag (1 without one)."""
    values = _tag_value(memoryview(data), _ORIENTATION_TAG)
    return values[0] if values else 1


def displayed_size(size: tuple[int, int], orientation: int) -> tuple[int, int]:
    """(width, height) of an image stored ``size`` once shown in ``orientation``: 5-8 turn it
    a quarter."""
    return (size[1], size[0]) if orientation >= 5 else size


def apply_orientation(image: NDArray[Any], orientation: int) -> NDArray[Any]:
    """``image`` (H, W[, C]) as displayed under EXIF ``orientation``: the same array for 1."""
    turned = {
        2: lambda a: a[:, ::-1],
        3: lambda a: a[::-1, ::-1],
        4: lambda a: a[::-1],
        5: lambda a: a.swapaxes(0, 1),
        6: lambda a: np.rot90(a, -1),
        7: lambda a: a.swapaxes(0, 1)[::-1, ::-1],
        8: lambda a: np.rot90(a, 1),
    }.get(orientation)
    return image if turned is None else np.ascontiguousarray(turned(image))


def declared_top(data: bytes | memoryview) -> int | None:
    """The largest sample value a 16-bit PNG (``sBIT``: its largest colour depth) or TIFF
    (``MaxSampleValue``) declares, or None where it declares none below 65535."""
    view = memoryview(data)
    try:
        if bytes(view[:8]) == b"\x89PNG\r\n\x1a\n":
            sbit = _chunks(view, 8, big=True).get(b"sBIT")
            colour = {1: 1, 2: 1, 3: 3, 4: 3}.get(len(sbit) if sbit is not None else 0)
            bits = max(sbit[:colour]) if sbit is not None and colour else 16
            return 2**bits - 1 if 1 <= bits < 16 else None
    except (struct.error, ValueError):
        return None
    values = [v for v in _tag_value(view, _MAX_SAMPLE_VALUE_TAG) if v > 0]
    return max(values) if values and max(values) < 65535 else None


def sixteen_bit_top(image: NDArray[np.uint16], declared: int | None) -> int:
    """The sample value of a 16-bit ``image`` that becomes 255 (see the module docstring):
    ``declared`` when the colour samples fit in it, else the top of the smallest of 10, 12, 14
    and 16 bits holding the largest of them."""
    colour = image[..., :3] if image.ndim == 3 else image
    largest = int(colour.max()) if colour.size else 0
    if declared is not None and largest <= declared:
        return declared
    bits = next(b for b in _DEPTHS if largest < 2**b)
    return 2**bits - 1
