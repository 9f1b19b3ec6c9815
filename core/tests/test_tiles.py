"""Tile handles: page-cache backed, zero-copy until decode, clear errors."""

from __future__ import annotations

import mmap
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.tiles import MmapTileHandle, decode_image, read_image

REPO = Path(__file__).resolve().parents[2]
ORTHO = REPO / "data" / "imagery" / "open_orthophotos" / "test_tiled.tif"


def test_file_handle_reads_on_demand_and_holds_no_mapping(tmp_path):
    image = cv2.imread(str(ORTHO), cv2.IMREAD_COLOR)[:256, :256]
    path = tmp_path / "tile.png"
    cv2.imwrite(str(path), image)
    handle = MmapTileHandle(path)
    assert not any(isinstance(v, mmap.mmap) for v in vars(handle).values())  # no SIGBUS risk
    view = handle.encoded()
    assert view.readonly and view.nbytes == path.stat().st_size
    rgb = handle.decode()
    assert rgb.shape == (256, 256, 3) and rgb.flags.owndata
    np.testing.assert_array_equal(rgb, image[:, :, ::-1])


def test_four_band_geotiff_decodes_to_rgb():
    rgb = read_image(
        REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"
    )
    assert rgb.dtype == np.uint8 and rgb.shape == (723, 934, 3)


def test_bad_inputs_are_named(tmp_path):
    with pytest.raises(InvalidInputError, match="no such image file"):
        read_image(tmp_path / "missing.png")
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    with pytest.raises(InvalidInputError, match="empty.png"):
        MmapTileHandle(empty)
    junk = tmp_path / "junk.jpg"
    junk.write_bytes(b"not an image at all")
    with pytest.raises(InvalidInputError, match="junk.jpg.*not a decodable image"):
        MmapTileHandle(junk).decode()
    with pytest.raises(InvalidInputError, match="no bytes"):
        decode_image(b"", "x")


def test_a_tiff_whose_first_ifd_follows_its_pixels_is_decoded_and_sized(tmp_path):
    """libtiff (OpenCV, GDAL) writes the IFD after the pixel data: past the first MiB of a
    frame of 1024x768 it was refused as "not a decodable image"."""
    import io
    import struct

    from c3_matcher.tiles import image_file_size

    image = np.random.default_rng(0).integers(0, 256, (768, 1024, 3), dtype=np.uint8)
    ok, encoded = cv2.imencode(".tif", image)
    data = encoded.tobytes()
    assert ok and struct.unpack("<I", data[4:8])[0] > 1 << 20  # its IFD lies past 1 MiB
    assert np.array_equal(decode_image(data, "frame.tif"), image[:, :, ::-1])
    path = tmp_path / "frame.tif"
    path.write_bytes(data)
    assert read_image(path).shape == (768, 1024, 3)
    with path.open("rb") as fh:
        assert image_file_size(fh) == (1024, 768)
    ifd = struct.unpack("<I", data[4:8])[0]
    assert image_file_size(io.BytesIO(data[: ifd + 4])) is None  # its IFD cut off: no size
