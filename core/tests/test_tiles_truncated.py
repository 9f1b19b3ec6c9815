"""A PNG cut short (a tile or the query) is refused before it is decoded, as an image that is not
decodable, with a message saying it is cut short: libpng, given one, wrote its own line to the
process's stderr ("libpng error: PNG input buffer is incomplete") beside the product's one-line
refusal, and a flight process's stderr is the host's. A JPEG cut short is refused by OpenCV's
decoder without a word on stderr, so it is left to it. ``capfd`` reads the file descriptor."""

from __future__ import annotations

import dataclasses
import os
import shutil
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher.fdr import InMemoryFdr
from c3_matcher.testing import ScriptedCandidate, ScriptedRig
from c3_matcher.tiles import BytesTileHandle, ImageDecodeError, decode_image, read_image

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "data" / "demo"
PNG = (DEMO / "tile_a.png").read_bytes()
JPEG = (DEMO / "frame.jpg").read_bytes()
CUT_SHORT = "cut short"


@pytest.mark.parametrize(
    "data",
    [PNG[: len(PNG) // 2], PNG[:-12], PNG[:-1], PNG[:200]],
    ids=["half", "no IEND", "one byte short", "header only"],
)
def test_a_png_cut_short_is_refused_before_decoding_and_libpng_says_nothing(
    capfd: pytest.CaptureFixture[str], data: bytes
) -> None:
    capfd.readouterr()
    with pytest.raises(ImageDecodeError) as refused:
        decode_image(data, "tile.png")
    assert str(refused.value).startswith("tile.png: ") and CUT_SHORT in str(refused.value)
    assert capfd.readouterr().err == ""


def test_a_png_whole_or_with_bytes_after_its_end_decodes_as_before(
    capfd: pytest.CaptureFixture[str],
) -> None:
    whole = decode_image(PNG, "tile.png")
    for after in (64, 64 << 10):  # libpng reads no further than IEND, whatever follows
        np.testing.assert_array_equal(decode_image(PNG + b"\0" * after, "tile.png"), whole)
    expected = cv2.imdecode(np.frombuffer(PNG, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
    np.testing.assert_array_equal(whole, expected)
    assert capfd.readouterr().err == ""


def test_a_jpeg_cut_short_is_refused_without_a_word_on_stderr(
    capfd: pytest.CaptureFixture[str],
) -> None:
    capfd.readouterr()
    for data in (JPEG[: len(JPEG) // 2], JPEG[:-2]):
        with pytest.raises(ImageDecodeError, match="not a decodable image"):
            decode_image(data, "frame.jpg")
    assert capfd.readouterr().err == ""


def test_match_with_a_png_cut_short_says_one_line_exit_2(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)
    monkeypatch.setenv("C3_MATCHER_FDR__PATH", str(tmp_path / "fdr.jsonl"))
    cut = tmp_path / "cut.png"
    cut.write_bytes(PNG[: len(PNG) // 2])
    query = tmp_path / "frame.png"
    query.write_bytes(cv2.imencode(".png", cv2.imread(str(DEMO / "frame.jpg")))[1].tobytes()[:-5])
    shutil.copy(DEMO / "calibration.json", tmp_path / "calibration.json")
    runs = [
        (["--query", str(DEMO / "frame.jpg"), "--tile", str(cut)], f"--tile {cut}: "),
        (["--query", str(query), "--tile", str(DEMO / "tile_a.png")], f"{query}: "),
    ]
    for argv, named in runs:
        capfd.readouterr()
        assert main(["match", *argv, "--tile-gsd", "0.097", "--height", "27"]) == 2
        out, err = capfd.readouterr()
        lines = [x for x in err.splitlines() if not x.startswith("c3-matcher match: warning")]
        assert out == "" and len(lines) == 1, err
        assert lines[0].startswith(f"c3-matcher: {named}") and CUT_SHORT in lines[0], err


def test_a_tile_cut_short_in_flight_is_a_decode_failure_dropped_in_silence(
    fdr: InMemoryFdr, capfd: pytest.CaptureFixture[str]
) -> None:
    S = ScriptedCandidate
    rig = ScriptedRig([S(100), S(100), S(90)], fdr)
    second = rig.rerank.candidates[1]
    cut = BytesTileHandle(PNG[: len(PNG) // 2], "tile 15/1/2")
    odd = dataclasses.replace(second, tile_pixels_handle=cut)
    rig.rerank = dataclasses.replace(
        rig.rerank, candidates=(rig.rerank.candidates[0], odd, rig.rerank.candidates[2])
    )
    capfd.readouterr()
    result = rig.match()
    assert result.candidates_dropped == 1 and len(result.per_candidate) == 2
    (record,) = fdr.of_kind("matcher.backbone_error")
    assert record["phase"] == "tile_decode" and CUT_SHORT in record["error"]
    assert "libpng" not in capfd.readouterr().err


def test_read_image_of_a_png_cut_short_names_the_file(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    cut = tmp_path / "cut.png"
    cut.write_bytes(PNG[:-12])
    capfd.readouterr()
    with pytest.raises(ImageDecodeError, match=f"{cut}: .*{CUT_SHORT}"):
        read_image(cut)
    assert capfd.readouterr().err == ""


def _chunk_at(data: bytes, kind: bytes) -> int:
    """Where the first chunk of ``kind`` starts (its length field)."""
    return data.index(kind) - 4


def _flip(data: bytes, at: int) -> bytes:
    damaged = bytearray(data)
    damaged[at] ^= 0xFF
    return bytes(damaged)


@pytest.mark.parametrize(
    ("kind", "offset"), [(b"IDAT", 1000), (b"IHDR", 12), (b"IEND", 8)], ids=["IDAT", "IHDR", "IEND"]
)
def test_a_png_whose_critical_chunk_fails_its_crc_is_refused_naming_it_and_libpng_says_nothing(
    capfd: pytest.CaptureFixture[str], kind: bytes, offset: int
) -> None:
    """A damaged copy (a flipped byte in the pixels, in the header's size, in the end chunk's
    CRC) is refused as damaged, naming the chunk, before its header's size is believed; libpng
    had written "libpng error: IDAT: CRC error" to fd 2 (and a flipped height was refused as
    an image over the pixel limit)."""
    at = PNG.rindex(b"IEND") - 4 if kind == b"IEND" else _chunk_at(PNG, kind)
    capfd.readouterr()
    with pytest.raises(ImageDecodeError) as refused:
        decode_image(_flip(PNG, at + offset), "tile.png")
    assert str(refused.value) == (
        f"tile.png: a damaged PNG: its {kind.decode()} chunk at byte {at} fails its CRC check"
    )
    assert capfd.readouterr().err == ""


def test_a_png_with_a_damaged_ancillary_chunk_decodes_as_before() -> None:
    """An ancillary chunk (here a text comment) is libpng's to judge: it skips a damaged one
    and decodes the image, so the image is not refused for it."""
    text = b"tEXtComment\0tile"
    ihdr_end = 8 + 12 + 13
    for crc in (zlib.crc32(text), zlib.crc32(text) ^ 1):
        chunk = struct.pack(">I", len(text) - 4) + text + struct.pack(">I", crc)
        with_text = PNG[:ihdr_end] + chunk + PNG[ihdr_end:]
        np.testing.assert_array_equal(decode_image(with_text, "t"), decode_image(PNG, "t"))
