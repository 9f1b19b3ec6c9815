"""Every import checks each photo with ``image_problem`` before writing a flight: read its size
from the header (an image of another size is never decoded, however large it says it is), then
decode it as the matcher will, so that a damaged copy is refused quietly, naming why."""

from __future__ import annotations

import struct
import time
import zlib

import cv2
import numpy as np
import pytest

from c3_matcher_tools.dataset.sources.writer import image_problem

SIZE = (96, 64)


def _png(width: int, height: int) -> bytes:
    rng = np.random.default_rng(0)
    ok, buf = cv2.imencode(".png", rng.integers(0, 255, (height, width, 3), dtype=np.uint8))
    assert ok
    return buf.tobytes()


def test_a_whole_photo_of_the_calibrated_size_has_no_problem() -> None:
    assert image_problem(_png(*SIZE), SIZE) is None


def test_a_damaged_png_is_not_readable_naming_the_damage_and_libpng_says_nothing(
    capfd: pytest.CaptureFixture[str],
) -> None:
    """libpng had written "libpng error: IDAT: CRC error" to stderr beside the refusal."""
    damaged = bytearray(_png(*SIZE))
    damaged[damaged.index(b"IDAT") + 40] ^= 0xFF
    capfd.readouterr()
    problem = image_problem(bytes(damaged), SIZE)
    assert problem is not None
    assert problem.startswith("not a readable image: a damaged PNG: its IDAT chunk")
    assert capfd.readouterr().err == ""


def test_a_photo_claiming_a_huge_other_size_is_refused_from_its_header_undecoded() -> None:
    """A header saying 40000 x 40000 px (1.6 Gpx of zeros behind a few kB) was decoded whole
    before its size was compared with the calibration's."""
    ihdr = b"IHDR" + struct.pack(">IIBBBBB", 40000, 40000, 8, 0, 0, 0, 0)
    idat = b"IDAT" + zlib.compress(b"\0" * (40001 * 64))
    png = b"\x89PNG\r\n\x1a\n"
    for chunk in (ihdr, idat, b"IEND"):
        png += struct.pack(">I", len(chunk) - 4) + chunk + struct.pack(">I", zlib.crc32(chunk))
    start = time.perf_counter()
    assert image_problem(png, SIZE) == "is 40000x40000 px, the calibration says 96x64"
    assert time.perf_counter() - start < 0.5


def test_a_photo_above_the_matchers_default_pixel_limit_is_checked_as_the_camera_says() -> None:
    """A survey camera's photo (here 7100 x 7100 px, 50.4 Mpx: over the default 50 Mpx limit)
    of the calibrated size is readable: the import's check is bounded by the camera's size, not
    by a pixel limit the flight's replay is given (the first version refused it, naming a
    setting the import never read)."""
    side = 7100
    ok, buf = cv2.imencode(".png", np.zeros((side, side), np.uint8))
    assert ok
    assert image_problem(buf.tobytes(), (side, side)) is None
