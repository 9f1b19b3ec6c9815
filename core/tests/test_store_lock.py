"""A tile store locked by another process never stalls a frame: the first read fails within
SQLite's short busy timeout (it waited 5 s, then 5 s more for the probe), the outage is said
once (ERROR log, FDR record), later reads fail at once, and once the lock is gone the store is
tried again after ``retry_s`` and serves tiles. A real lock held by a real second process on a
copy of a shipped store."""

from __future__ import annotations

import shutil
import sqlite3
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.tilestore.mbtiles import MBTilesStore, TileStoreUnusableError

STORE = Path(__file__).resolve().parents[2] / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
BOUND_S = 2.0  # far above the busy timeout, far below the 10 s a locked store used to cost

_HOLDER = textwrap.dedent("""
    import sqlite3, sys
    db = sqlite3.connect(sys.argv[1], isolation_level=None)
    db.execute("PRAGMA locking_mode=EXCLUSIVE")
    db.execute("BEGIN EXCLUSIVE")
    print("locked", flush=True)
    sys.stdin.readline()
    db.execute("COMMIT")
    db.close()
    print("released", flush=True)
""")


class _Lock:
    """An EXCLUSIVE lock on ``path`` held by another process until ``release()``."""

    def __init__(self, path: Path) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, "-c", _HOLDER, str(path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self._proc.stdout is not None and self._proc.stdout.readline().strip() == "locked"

    def release(self) -> None:
        if self._proc.poll() is None:
            out, _ = self._proc.communicate("\n", timeout=30)
            assert "released" in out


@pytest.fixture
def store_copy(tmp_path: Path) -> Iterator[tuple[Path, tuple[int, int, int]]]:
    path = tmp_path / "tiles.mbtiles"
    shutil.copy2(STORE, path)
    with sqlite3.connect(path) as db:
        z, x, row = db.execute("SELECT zoom_level, tile_column, tile_row FROM tiles").fetchone()
    yield path, (z, x, (1 << z) - 1 - row)


def test_a_locked_store_fails_fast_is_said_once_and_serves_again_after_release(store_copy):
    from c3_matcher.logs import configure_logging

    path, key = store_copy
    now = [0.0]
    store = MBTilesStore(path, retry_s=5.0, clock=lambda: now[0])
    assert store.tile_bytes(*key) is not None
    store._close_connections()  # fresh connections: the lock is taken while none is open
    fdr = InMemoryFdr()
    handle = configure_logging(fdr, level="WARNING")
    lock = _Lock(path)
    try:
        started = time.perf_counter()
        with pytest.raises(TileStoreUnusableError, match="locked"):
            store.tile_bytes(*key)
        assert time.perf_counter() - started < BOUND_S
        for _ in range(5):  # every later frame: at once, no new report
            with pytest.raises(TileStoreUnusableError):
                store.tile_bytes(*key)
        lock.release()
        with pytest.raises(TileStoreUnusableError):  # not tried again before retry_s
            store.tile_bytes(*key)
        now[0] = 5.0
        assert store.tile_bytes(*key) is not None  # tried again: served
    finally:
        lock.release()
        handle.close()
        store.close()
    kinds = [p.get("kind") for p in fdr.of_kind("log.error") + fdr.of_kind("log.warning")]
    assert kinds.count("c3.tilestore.unusable") == 1
    assert kinds.count("c3.tilestore.recovered") == 1


def test_a_store_locked_at_open_is_named_as_locked_without_waiting(store_copy):
    path, _ = store_copy
    lock = _Lock(path)
    try:
        started = time.perf_counter()
        with pytest.raises(InvalidInputError, match="locked by another process"):
            MBTilesStore(path)
        assert time.perf_counter() - started < BOUND_S
    finally:
        lock.release()
    MBTilesStore(path).close()
