"""An image's size is believed only as its decoder reads it: a TIFF whose first IFD gives its
width or height twice (libtiff decodes the first, a check keeping the last would pass a bomb) is
refused, naming the file, before it is decoded; and an image that decodes above
``max_image_pixels`` whatever its header said is refused after."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher import tiles
from c3_matcher.tiles import (
    ImageDecodeError,
    decode_image,
    image_file_size,
    image_header_size,
    read_image,
)

LIMIT = 1024  # px: the smallest images keep the test cheap


def _tiff(width: int, height: int, repeated: tuple[int, int] | None) -> bytes:
    """A grey 8-bit TIFF of ``width`` x ``height`` px in one deflated strip; ``repeated``: a
    second width and height appended to its IFD (the size a last-wins reader would take)."""
    strip = zlib.compress(b"\x80" * (width * height))
    entries = [(256, 4, width), (257, 4, height), (258, 3, 8), (259, 3, 8), (262, 3, 1)]
    entries += [(273, 4, 0), (277, 3, 1), (278, 4, height), (279, 4, len(strip))]
    if repeated is not None:
        entries += [(256, 4, repeated[0]), (257, 4, repeated[1])]
    data_at = 8 + 2 + 12 * len(entries) + 4
    out = bytearray(b"II*\x00" + struct.pack("<IH", 8, len(entries)))
    for tag, typ, value in entries:
        value = data_at if tag == 273 else value
        packed = struct.pack("<HH", value, 0) if typ == 3 else struct.pack("<I", value)
        out += struct.pack("<HHI", tag, typ, 1) + packed
    return bytes(out + struct.pack("<I", 0) + strip)


def test_the_tiff_without_a_repeat_decodes_at_its_size() -> None:
    image = decode_image(_tiff(30, 20, None), "honest.tif", LIMIT)
    assert image.shape == (20, 30, 3)


def test_a_tiff_giving_its_size_twice_is_refused_naming_the_file(tmp_path: Path) -> None:
    bomb = tmp_path / "bomb.tif"
    bomb.write_bytes(_tiff(64, 64, (16, 16)))  # decoded 4096 px, a last-wins check saw 256
    with pytest.raises(ImageDecodeError) as refused:
        read_image(bomb, LIMIT)
    assert str(bomb) in str(refused.value)
    assert "first IFD gives its width (tag 256) twice" in str(refused.value)
    assert image_header_size(bomb.read_bytes()) is None
    with bomb.open("rb") as fh:
        assert image_file_size(fh) is None


def test_an_image_decoded_above_the_limit_is_refused_whatever_its_header_said(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    ok, png = cv2.imencode(".png", np.full((64, 64, 3), 90, np.uint8))
    assert ok
    for reader in ("_header_size", "image_header_size"):  # a header misread
        monkeypatch.setattr(tiles, reader, lambda head: (16, 16), raising=False)
    with pytest.raises(ImageDecodeError, match=r"decoded to 64x64 px, above the limit of 1024"):
        decode_image(png.tobytes(), "misread.png", LIMIT)
