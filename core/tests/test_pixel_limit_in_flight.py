"""``[matcher] max_image_pixels`` bounds what the composed matcher decodes, not only what the
command line reads: a candidate whose tile (an image file's handle as the README makes it, a
tile in memory, a store's window) is above it is dropped, refused before decoding, by its own
error naming the limit; one at the limit is matched. A handle that takes no limit (one of
another's, with ``decode()`` alone) still works, its pixels refused once decoded when above it.

The real path: the README's Python example (the shipped demo flight's store windows, the demo
frame's tile files), composed by ``compose_root`` with the OpenCV strategy (no engines), and
``match --store`` under a configuration file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from c3_matcher import (
    C3Settings,
    InsufficientInliersError,
    RerankCandidate,
    RerankResult,
    TileId,
    build_default_helpers,
    compose_root,
    load_calibration,
)
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.tile_limit import decode_within
from c3_matcher.tiles import BytesTileHandle, ImageDecodeError, MmapTileHandle
from c3_matcher.tilestore import MBTilesStore
from c3_matcher.tilestore.base import tile_centre_id

from .demo_match import DEMO, FLIGHT, WINDOW, flight_frame, run_match

DEMO_TILE = 512  # the demo frame's tile files, px square


def _match(limit: int, candidates: list[RerankCandidate]) -> tuple[object, InMemoryFdr]:
    """The README's example under ``max_image_pixels = limit``: its result, or the
    InsufficientInliersError raised, and the FDR's records."""
    settings = C3Settings(matcher={"strategy": "sift_magsac", "max_image_pixels": limit})
    fdr = InMemoryFdr()
    helpers = {**build_default_helpers(settings), "c13_fdr": fdr}
    root = compose_root(settings, helpers, configure_logs=False)
    frame, calibration = flight_frame()[0], load_calibration(FLIGHT / "calibration.json")
    try:
        rerank = RerankResult(frame.frame_id, tuple(candidates))
        try:
            return root.matcher.match(frame, rerank, calibration), fdr
        except InsufficientInliersError as exc:
            return exc, fdr
    finally:
        root.close()


def _dropped_for(fdr: InMemoryFdr) -> list[str]:
    return [r["error"] for r in fdr.of_kind("matcher.backbone_error")]


def test_the_readme_example_drops_store_windows_above_the_configured_limit() -> None:
    record = json.loads((FLIGHT / "frames.jsonl").read_text().splitlines()[0])
    with MBTilesStore(FLIGHT / "tiles.mbtiles") as store:
        candidates = [
            store.candidate(TileId(*c["tile_id"]), c["score"], size_px=WINDOW)
            for c in record["candidates"]
        ]
        refused, fdr = _match(WINDOW * WINDOW - 1, candidates)
        assert isinstance(refused, InsufficientInliersError), refused
        said = _dropped_for(fdr)
        assert len(said) == len(candidates) == 3
        limit = f"{WINDOW}x{WINDOW} px exceeds the limit of {WINDOW * WINDOW - 1} px"
        assert all(limit in s and "refused before decoding" in s for s in said), said
        matched, fdr = _match(WINDOW * WINDOW, candidates)
    assert not isinstance(matched, Exception), matched
    assert _dropped_for(fdr) == []


def test_the_readme_example_drops_tile_files_above_the_configured_limit() -> None:
    tiles = [MmapTileHandle(DEMO / f"tile_{c}.png") for c in "ab"]
    tiles.append(BytesTileHandle((DEMO / "tile_c.png").read_bytes(), "tile_c"))
    candidates = [
        RerankCandidate(TileId(21, 0.0, float(i)), 1.0, h, 0.0968) for i, h in enumerate(tiles)
    ]
    refused, fdr = _match(DEMO_TILE * DEMO_TILE - 1, candidates)
    assert isinstance(refused, InsufficientInliersError), refused
    said = _dropped_for(fdr)
    limit = f"image of 512x512 px exceeds the limit of {DEMO_TILE * DEMO_TILE - 1} px"
    assert len(said) == 3 and all(limit in s for s in said), said


def test_match_store_drops_a_window_above_the_configured_limit(tmp_path: Path) -> None:
    record = json.loads((FLIGHT / "frames.jsonl").read_text().splitlines()[0])
    zoom, lat, lon = record["candidates"][0]["tile_id"]
    config = tmp_path / "c3.toml"
    config.write_text("[matcher]\nmax_image_pixels = 200000\n")
    argv = [
        *("--config", str(config), "match", "--query", str(FLIGHT / record["image"])),
        *("--store", str(FLIGHT / "tiles.mbtiles"), "--window", str(WINDOW)),
        *("--tile-id", f"{zoom},{lat!r},{lon!r}", "--strategy", "sift_magsac"),
        *("--calibration", str(FLIGHT / "calibration.json"), "--height", str(record["height_m"])),
        *("--attitude", ",".join(map(str, record["attitude_deg"]))),
        *("--fdr", str(tmp_path / "fdr.jsonl")),
    ]
    proc = run_match(argv=argv)
    assert proc.returncode == 3, proc.stderr[-2000:]
    assert json.loads(proc.stdout)["error"] == "InsufficientInliersError"
    assert "448x448 px exceeds the limit of 200000 px" in proc.stderr


def test_the_handles_take_a_limit_and_keep_their_own() -> None:
    png = (DEMO / "tile_a.png").read_bytes()
    for handle in (MmapTileHandle(DEMO / "tile_a.png"), BytesTileHandle(png)):
        assert handle.decode().shape == (512, 512, 3)  # the default, 50 Mpx
        assert handle.decode_within(512 * 512).shape == (512, 512, 3)
        with pytest.raises(ImageDecodeError, match=r"exceeds the limit of 262143 px"):
            handle.decode_within(512 * 512 - 1)
    own = BytesTileHandle(png, "own", max_pixels=1000)
    with pytest.raises(ImageDecodeError, match=r"exceeds the limit of 1000 px"):
        own.decode_within(10**6)  # the tighter of the two


def test_a_store_window_above_the_limit_reads_no_tile() -> None:
    with MBTilesStore(FLIGHT / "tiles.mbtiles") as store:
        x, y = next(iter(store.tiles(15)))
        reads: list[tuple[int, int, int]] = []
        counted = store.tile_bytes

        def counting(zoom: int, tx: int, ty: int) -> memoryview | None:
            reads.append((zoom, tx, ty))
            return counted(zoom, tx, ty)

        store.tile_bytes = counting  # type: ignore[method-assign]
        window = store.handle(tile_centre_id(15, x, y), size_px=WINDOW)
        with pytest.raises(ImageDecodeError, match=r"448x448 px exceeds the limit of 200000"):
            window.decode_within(200_000)
        tile = store.handle(tile_centre_id(15, x, y), size_px=256)
        with pytest.raises(ImageDecodeError, match=r"256x256 px exceeds the limit of 65535"):
            tile.decode_within(256 * 256 - 1)
        assert reads == []
        assert window.decode_within(WINDOW * WINDOW).shape == (WINDOW, WINDOW, 3)
        assert tile.decode_within(256 * 256).shape == (256, 256, 3)


class DecodeOnly:
    """A handle of another's, made before ``decode_within``: ``encoded()`` and ``decode()``."""

    def __init__(self, side: int) -> None:
        self.side = side

    def encoded(self) -> memoryview:
        return memoryview(b"")

    def decode(self) -> np.ndarray:
        return np.zeros((self.side, self.side, 3), np.uint8)


def test_a_handle_that_takes_no_limit_still_works_and_is_held_to_it_once_decoded() -> None:
    assert decode_within(DecodeOnly(64), 64 * 64, "tile 1").shape == (64, 64, 3)
    with pytest.raises(ImageDecodeError, match=r"tile 1: decoded by its handle \(DecodeOnly\)"):
        decode_within(DecodeOnly(65), 64 * 64, "tile 1")
