"""Frames as cameras write them, on a shipped frame: the EXIF orientation is applied (the frame
is the image as displayed, its size in the header too), and 10-, 12- or 14-bit samples held in
16-bit PNG or TIFF words keep their grey levels (they were divided by 257: 4 or 16 levels),
while 8-bit frames and 16-bit ones using the whole range decode as they always did."""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
from PIL import Image

from c3_matcher.image_tags import exif_orientation
from c3_matcher.tiles import ImageDecodeError, decode_image, image_header_size

REPO = Path(__file__).resolve().parents[2]
FRAME = REPO / "data" / "flights" / "naip_demo" / "frames" / "000000.jpg"

#: PIL's transpose of the stored pixels that displays each EXIF orientation
_SHOWN = {
    2: Image.Transpose.FLIP_LEFT_RIGHT,
    3: Image.Transpose.ROTATE_180,
    4: Image.Transpose.FLIP_TOP_BOTTOM,
    5: Image.Transpose.TRANSPOSE,
    6: Image.Transpose.ROTATE_270,
    7: Image.Transpose.TRANSVERSE,
    8: Image.Transpose.ROTATE_90,
}


def _frame_rgb() -> np.ndarray:
    return np.ascontiguousarray(cv2.imread(str(FRAME), cv2.IMREAD_COLOR)[:, :, ::-1])


def _jpeg(stored: Image.Image, orientation: int | None) -> bytes:
    out = io.BytesIO()
    extra = {}
    if orientation is not None:
        exif = Image.Exif()
        exif[0x0112] = orientation
        extra["exif"] = exif.tobytes()
    stored.save(out, "JPEG", quality=95, **extra)
    return out.getvalue()


@pytest.mark.parametrize("orientation", range(2, 9))
def test_a_jpeg_is_decoded_as_its_exif_orientation_shows_it(orientation: int) -> None:
    stored = Image.fromarray(_frame_rgb())
    plain = decode_image(_jpeg(stored, None), "plain", as_displayed=True)
    tagged = _jpeg(stored, orientation)
    shown = np.asarray(Image.fromarray(plain).transpose(_SHOWN[orientation]))
    got = decode_image(tagged, "tagged", as_displayed=True)
    assert got.shape == shown.shape and np.array_equal(got, shown)
    assert image_header_size(tagged) == (got.shape[1], got.shape[0])


def test_a_frame_stored_upside_down_decodes_upright() -> None:
    """The camera's case: pixels stored turned, Orientation 3, every viewer upright."""
    upright = _frame_rgb()
    tagged = _jpeg(Image.fromarray(upright).transpose(Image.Transpose.ROTATE_180), 3)
    error = np.abs(decode_image(tagged, "f", as_displayed=True).astype(int) - upright).mean()
    assert error < 3.0, error


@pytest.mark.parametrize("orientation", [None, 1])
def test_a_jpeg_without_a_turn_decodes_as_stored(orientation: int | None) -> None:
    data = _jpeg(Image.fromarray(_frame_rgb()), orientation)
    want = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)[:, :, ::-1]
    assert np.array_equal(decode_image(data, "f", as_displayed=True), want)


def _png16(image: np.ndarray, sbit: int | None = None) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    assert ok
    data = buf.tobytes()
    if sbit is None:
        return data
    channels = 1 if image.ndim == 2 else 3
    body = b"sBIT" + bytes([sbit] * channels)
    chunk = struct.pack(">I", channels) + body + struct.pack(">I", zlib.crc32(body))
    return data[:33] + chunk + data[33:]  # right after IHDR


@pytest.mark.parametrize(("bits", "scale"), [(10, 4), (12, 16), (14, 64)])
def test_camera_depths_in_16_bit_words_keep_their_grey_levels(bits: int, scale: int) -> None:
    rgb = _frame_rgb()
    frame = rgb[:, :, ::-1].astype(np.uint16) * scale  # 8-bit detail, N-bit words
    got = decode_image(_png16(frame), f"{bits}-bit", as_displayed=True)
    want = (frame.astype(np.uint32) * 255 // (2**bits - 1)).astype(np.uint8)[:, :, ::-1]
    assert np.array_equal(got, want)
    assert len(np.unique(got)) >= len(np.unique(rgb)) - 5  # not 4 or 16 levels
    assert np.abs(got.astype(int) - rgb).max() <= 1


def test_a_declared_depth_gives_a_dark_frame_the_camera_scale() -> None:
    grey = cv2.cvtColor(_frame_rgb(), cv2.COLOR_RGB2GRAY).astype(np.uint16) * 4  # max < 1024
    declared = decode_image(_png16(grey, sbit=12), "sBIT 12", as_displayed=True)
    assert np.array_equal(declared[:, :, 0], (grey.astype(np.uint32) * 255 // 4095))
    # read as 10-bit: 4x brighter
    undeclared = decode_image(_png16(grey), "no sBIT", as_displayed=True)
    assert np.array_equal(undeclared[:, :, 0], (grey.astype(np.uint32) * 255 // 1023))
    tiff = io.BytesIO()
    tifffile.imwrite(tiff, grey, extratags=[(281, "H", 1, 4095, True)])
    from_tiff = decode_image(tiff.getvalue(), "tiff", as_displayed=True)
    assert np.array_equal(from_tiff[:, :, 0], declared[:, :, 0])


def test_16_bit_frames_using_the_whole_range_divide_by_257() -> None:
    full = _frame_rgb()[:, :, ::-1].astype(np.uint16) * 257
    full[0, 0, 0] = 65535
    want = (full // 257).astype(np.uint8)[:, :, ::-1]
    assert np.array_equal(decode_image(_png16(full), "16-bit", as_displayed=True), want)
    scaled = _png16(full, sbit=12)  # PNG's own way: 12 bits scaled up to the 16-bit range
    assert np.array_equal(decode_image(scaled, "sBIT 12, full range", as_displayed=True), want)


def test_a_tiff_stored_turned_a_quarter_is_refused_naming_its_tag() -> None:
    tiff = io.BytesIO()
    tifffile.imwrite(tiff, _frame_rgb()[:64, :96], extratags=[(274, "H", 1, 6, True)])
    with pytest.raises(ImageDecodeError, match="Orientation tag is 6"):
        decode_image(tiff.getvalue(), "turned.tif", as_displayed=True)


def test_map_tiles_are_read_as_stored_one_16_bit_scale_for_all() -> None:
    """A tile's place is its grid's: an EXIF Orientation on a tile does not turn it; and one
    16-bit scale (/ 257) serves every tile, so two tiles of one dark scene meet without a seam
    (a per-tile depth put them 4x apart)."""
    stored = Image.fromarray(_frame_rgb())
    tagged = _jpeg(stored, 6)
    assert np.array_equal(decode_image(tagged, "tile"), decode_image(_jpeg(stored, None), "t"))
    dark = (np.arange(64, dtype=np.uint16)[None, :].repeat(8, 0) + 3000).astype(np.uint16)
    got = decode_image(_png16(np.dstack([dark] * 3)), "16-bit tile")
    assert np.array_equal(got[:, :, 0], (dark // 257).astype(np.uint8))


def test_a_tag_count_the_file_cannot_hold_is_no_tag() -> None:
    """A damaged EXIF Orientation entry counting 4 billion values made the reader build a format
    of 4 billion letters (8.5 GB, MemoryError; one such frame stopped a whole replay): a count
    beyond the file is no tag, the frame read as stored."""
    tiff = b"MM\x00*" + struct.pack(">I", 8) + struct.pack(">H", 1)
    tiff += struct.pack(">HHI", 274, 3, 0xFFFFFFFF) + struct.pack(">HH", 1, 0) + b"\0" * 4
    app1 = b"\xff\xe1" + struct.pack(">H", 2 + 6 + len(tiff)) + b"Exif\x00\x00" + tiff
    plain = _jpeg(Image.fromarray(_frame_rgb()), None)
    damaged = plain[:2] + app1 + plain[2:]
    assert exif_orientation(damaged) == 1
    assert decode_image(damaged, "f", as_displayed=True).shape == _frame_rgb().shape
