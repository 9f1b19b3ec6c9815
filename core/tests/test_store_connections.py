"""A tile store read from many short-lived threads keeps no connection of a thread that has
ended (no file descriptor per thread ever seen, which would run a vehicle's process out of
files), and a closed store refuses every read saying it is closed, opening nothing: inside the
matcher, its candidates are dropped (``tile_decode``) with that error, the contract's
``InsufficientInliersError`` when none is left. The demo flight's real tile store."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest

from c3_matcher.dto import RerankResult, TileId
from c3_matcher.errors import InsufficientInliersError
from c3_matcher.testing import ScriptedCandidate, ScriptedRig
from c3_matcher.tilestore.mbtiles import MBTilesStore, TileStoreUnusableError

REPO = Path(__file__).resolve().parents[2]
FLIGHT = REPO / "data" / "flights" / "naip_demo"


def _tile_id() -> TileId:
    first = json.loads((FLIGHT / "frames.jsonl").read_text().splitlines()[0])
    return TileId(*first["candidates"][0]["tile_id"])


def _open_files() -> int:
    return len(list(Path("/proc/self/fd").iterdir()))


def test_the_connections_of_ended_threads_are_closed(tmp_path) -> None:
    store = MBTilesStore(FLIGHT / "tiles.mbtiles")
    tile = _tile_id()
    try:
        store.candidate(tile, 1.0, size_px=448).tile_pixels_handle.decode()  # this thread's
        before = _open_files()
        failures: list[BaseException] = []

        def read() -> None:
            try:
                store.candidate(tile, 1.0, size_px=448).tile_pixels_handle.decode()
            except BaseException as exc:
                failures.append(exc)

        for _ in range(40):  # a thread per frame, each ended before the next starts
            thread = threading.Thread(target=read)
            thread.start()
            thread.join(30)
        assert failures == []
        assert _open_files() - before <= 1  # the last thread's, until the next is made
    finally:
        store.close()


def test_a_closed_store_refuses_reads_and_opens_nothing() -> None:
    store = MBTilesStore(FLIGHT / "tiles.mbtiles")
    handle = store.candidate(_tile_id(), 1.0, size_px=448).tile_pixels_handle
    store.close()
    before = _open_files()
    with pytest.raises(TileStoreUnusableError, match="closed"):
        handle.decode()
    with pytest.raises(TileStoreUnusableError, match="closed"):
        store.zooms()
    assert store.feature_store() is None
    assert _open_files() == before
    store.close()  # idempotent


def test_a_closed_stores_candidates_are_dropped_by_the_matcher(fdr) -> None:
    store = MBTilesStore(FLIGHT / "tiles.mbtiles")
    rig = ScriptedRig([ScriptedCandidate(100)], fdr)
    rig.rerank = RerankResult(rig.frame.frame_id, (store.candidate(_tile_id(), 1.0, 448),))
    store.close()
    with pytest.raises(InsufficientInliersError):
        rig.match()
    (dropped,) = fdr.of_kind("matcher.backbone_error")
    assert dropped["phase"] == "tile_decode" and "the store is closed" in dropped["error"]
