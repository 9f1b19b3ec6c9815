"""A tile file, or a tile store, that turns into a named pipe after it was checked is refused
when read, naming it, never waited on: opening a FIFO waits for a writer, which in flight never
comes (the frame would hang for good). The tile handle made on a file, an XYZ folder's tile whose
check saw a file, an MBTiles store replaced by a FIFO under a running matcher."""

from __future__ import annotations

import contextlib
import os
import shutil
import threading
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.tiles import MmapTileHandle
from c3_matcher.tilestore import xyz
from c3_matcher.tilestore.mbtiles import MBTilesStore, TileStoreUnusableError
from c3_matcher.tilestore.xyz import XyzTileStore

DATA = Path(__file__).resolve().parents[2] / "data"
TILE = DATA / "demo" / "tile_a.png"
STORE = DATA / "flights" / "naip_demo" / "tiles.mbtiles"
WAIT_S = 5.0  # a read that has not ended by then waits on the FIFO


def _outcome(read: Callable[[], object], fifo: Path) -> BaseException | None:
    """What ``read`` raised (None: it returned), run on a thread of its own; a read still
    waiting after ``WAIT_S`` (on the FIFO ``fifo``) is let go by a writer and fails the test."""
    got: list[BaseException | None] = []

    def run() -> None:
        try:
            read()
        except BaseException as exc:
            got.append(exc)
        else:
            got.append(None)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(WAIT_S)
    waited = thread.is_alive()
    while thread.is_alive():  # let the waiting reader go: a writer opens the FIFO and leaves
        with contextlib.suppress(OSError):
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        thread.join(0.1)
    assert not waited, f"the read waited on the FIFO {fifo} for {WAIT_S} s"
    return got[0]


def _turn_into_fifo(path: Path) -> None:
    path.unlink()
    os.mkfifo(path)


def test_a_tile_file_turned_into_a_fifo_after_its_handle_was_made_is_refused(
    tmp_path: Path,
) -> None:
    path = tmp_path / "tile.png"
    shutil.copy(TILE, path)
    handle = MmapTileHandle(path)
    assert handle.decode().shape == (512, 512, 3)
    _turn_into_fifo(path)
    for read in (handle.encoded, handle.decode):
        failed = _outcome(read, path)
        assert isinstance(failed, InvalidInputError), failed
        assert str(failed) == f"{path}: cannot read image file: it is a FIFO"


def test_an_xyz_tile_that_turns_into_a_fifo_after_its_check_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "xyz" / "3" / "2").mkdir(parents=True)
    path = tmp_path / "xyz" / "3" / "2" / "1.png"
    shutil.copy(TILE, path)
    store = XyzTileStore(tmp_path / "xyz")
    assert store.tile_bytes(3, 2, 1) is not None

    def checked_then_turned(tile: Path) -> MmapTileHandle:
        handle = MmapTileHandle(tile)  # the file checked: a regular one
        _turn_into_fifo(tile)  # and turned into a FIFO before it is opened
        return handle

    monkeypatch.setattr(xyz, "MmapTileHandle", checked_then_turned)
    failed = _outcome(lambda: store.tile_bytes(3, 2, 1), path)
    assert isinstance(failed, InvalidInputError), failed
    assert str(failed) == f"{path}: cannot read image file: it is a FIFO"


def test_a_tile_store_replaced_by_a_fifo_under_a_running_store_is_an_outage(
    tmp_path: Path,
) -> None:
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    with MBTilesStore(path, check_s=0.0) as store:
        z, (x, y) = 15, next(iter(store.tiles(15)))
        assert store.tile_bytes(z, x, y) is not None
        _turn_into_fifo(path)
        failed = _outcome(lambda: store.tile_bytes(z, x, y), path)
    assert isinstance(failed, TileStoreUnusableError), failed
    assert "it is a FIFO" in str(failed)
