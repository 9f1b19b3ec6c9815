"""A tile store follows its file while it runs: a store replaced by rename (``mv``,
``os.replace``) is served to every thread, one that read before included, once the store has
looked at the path again (at most ``check_s`` later); a store rewritten in place is read anew,
whether it now lacks the tile digests the old one had or keeps SQLite's change counter and size
(whose pages a connection could serve from its cache); and each change is said once (WARNING
``c3.tilestore.changed``, in the FDR). Copies of the shipped stores; the rewrites in place run
in a child process, as in test_tilestore_rewritten.py, so a signal fails the test instead of
killing pytest."""

from __future__ import annotations

import os
import shutil
import sqlite3
import textwrap
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.fdr import InMemoryFdr
from c3_matcher.logs import configure_logging
from c3_matcher.tilestore.mbtiles import MBTilesStore

from .test_tilestore_rewritten import OTHER, STORE, _run

CHANGED = "c3.tilestore.changed"


def _first_tile(path: Path) -> tuple[tuple[int, int, int], bytes]:
    """The first stored tile of the store ``path``: its XYZ key and its bytes."""
    with MBTilesStore(path) as store:
        zoom = store.zooms()[0]
        key = (zoom, *min(store.tiles(zoom)))
        blob = store.tile_bytes(*key)
        assert blob is not None
        return key, bytes(blob)


def _without_digests(source: Path, path: Path) -> Path:
    """A copy of the store ``source`` at ``path`` without its tile digests (as another tool
    writes one), vacuumed so that nothing of them is left in the file."""
    shutil.copy(source, path)
    db = sqlite3.connect(path)
    db.execute("DROP TABLE c3_tile_digest")
    db.commit()
    db.execute("VACUUM")
    db.close()
    return path


def _replace(path: Path, source: Path) -> None:
    """Put a copy of ``source`` at ``path`` by rename, as ``tiles build`` or ``mv`` does."""
    new = path.with_name(path.name + ".new")
    shutil.copy(source, new)
    os.replace(new, path)


def test_a_store_replaced_by_rename_is_served_to_a_thread_that_read_before(
    tmp_path: Path,
) -> None:
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    old_key, old_tile = _first_tile(path)
    new_key, new_tile = _first_tile(OTHER)
    now = [0.0]
    store = MBTilesStore(path, clock=lambda: now[0])
    try:
        with ThreadPoolExecutor(max_workers=1) as worker:  # one thread, reading again and again
            assert worker.submit(store.tile_bytes, *old_key).result() == old_tile
            assert store.tile_bytes(*old_key) == old_tile
            _replace(path, OTHER)
            now[0] += 1.0  # the store's CHECK_S: it looks at the path again
            assert worker.submit(store.tile_bytes, *new_key).result() == new_tile
            assert worker.submit(store.tile_bytes, *old_key).result() is None
            assert store.tile_bytes(*new_key) == new_tile
            assert store.tile_bytes(*old_key) is None
        assert store.metadata == MBTilesStore(OTHER).metadata
    finally:
        store.close()


def test_each_change_of_the_file_is_said_once(tmp_path: Path) -> None:
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    keys = [_first_tile(STORE)[0], _first_tile(OTHER)[0]]
    now = [0.0]
    store = MBTilesStore(path, clock=lambda: now[0])
    fdr = InMemoryFdr()
    handle = configure_logging(fdr, level="WARNING")
    said: list[int] = []
    try:
        with ThreadPoolExecutor(max_workers=2) as workers:
            for source in (OTHER, STORE):  # two changes, each read by many reads of two threads
                _replace(path, source)
                for _ in range(5):
                    now[0] += 1.0
                    list(workers.map(lambda k: store.tile_bytes(*k), keys * 4))
                changed = [p for p in fdr.of_kind("log.warning") if p.get("kind") == CHANGED]
                said.append(len(changed))
    finally:
        handle.close()
        store.close()
    assert said == [1, 2]
    assert all(p["store"] == str(path) for p in changed)


_NO_DIGESTS = textwrap.dedent("""
    import sys
    from pathlib import Path
    from c3_matcher.tilestore.mbtiles import MBTilesStore
    path, other = Path(sys.argv[1]), Path(sys.argv[2])
    with MBTilesStore(other) as source:
        zoom = source.zooms()[0]
        new = {(zoom, *xy): bytes(source.tile_bytes(zoom, *xy)) for xy in source.tiles(zoom)}
    store = MBTilesStore(path, clock=lambda: 0.0)  # never looks again unless a read fails
    zoom = store.zooms()[0]
    assert store.has_digests and store.tile_bytes(zoom, *min(store.tiles(zoom))) is not None
    path.write_bytes(other.read_bytes())  # in place, a store without digests now
    for _ in range(2):
        for key, tile in new.items():
            assert bytes(store.tile_bytes(*key)) == tile, key
    print("digests", store.has_digests, flush=True)
    store.close()
""")


def test_a_store_rewritten_in_place_without_digests_is_read_not_failed(tmp_path: Path) -> None:
    """The store was opened with tile digests: its reads joined their table, which the new
    file lacks, and every one failed until the store was opened again."""
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    other = _without_digests(OTHER, tmp_path / "other.mbtiles")
    assert _run(_NO_DIGESTS, str(path), str(other)).splitlines() == ["digests False"]


_SAME_SIZE = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from c3_matcher.tilestore.mbtiles import MBTilesStore
    path = Path(sys.argv[1])
    now = [0.0]
    store = MBTilesStore(path, clock=lambda: now[0])
    zoom = store.zooms()[0]
    key = (zoom, *min(store.tiles(zoom)))
    old = bytes(store.tile_bytes(*key))
    data = path.read_bytes()
    at, mid = data.find(old), len(old) // 2  # a small tile: its bytes lie in one page
    assert at > 100 and data.count(old) == 1
    new = old[:mid] + bytes(b ^ 0xFF for b in old[mid : mid + 16]) + old[mid + 16 :]
    time.sleep(0.05)  # a later write: another mtime, whatever the file system's tick
    with open(path, "r+b") as f:  # the header (its change counter) and the size kept
        f.seek(at + mid)
        f.write(new[mid : mid + 16])
    assert bytes(store.tile_bytes(*key)) in (old, new)  # within check_s: either
    now[0] += 1.0
    print("new" if bytes(store.tile_bytes(*key)) == new else "old", flush=True)
    store.close()
""")


def test_a_store_rewritten_in_place_keeping_its_size_and_counter_serves_the_new_bytes(
    tmp_path: Path,
) -> None:
    """SQLite keeps its cached pages while the file's change counter is the same, so a
    connection that read a tile before served its old bytes after such a rewrite."""
    path = _without_digests(STORE, tmp_path / "tiles.mbtiles")
    assert _run(_SAME_SIZE, str(path)).splitlines() == ["new"]


def test_a_store_whose_file_is_removed_keeps_serving_and_says_no_change(tmp_path: Path) -> None:
    """A removed file is no other map: the thread connected before goes on serving it (the
    others' reads are an outage, as they were), and no change is said."""
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    key, tile = _first_tile(path)
    now = [0.0]
    store = MBTilesStore(path, clock=lambda: now[0])
    fdr = InMemoryFdr()
    handle = configure_logging(fdr, level="WARNING")
    try:
        assert store.tile_bytes(*key) == tile
        path.unlink()
        now[0] += 1.0
        assert store.tile_bytes(*key) == tile
    finally:
        handle.close()
        store.close()
    assert [p for p in fdr.of_kind("log.warning") if p.get("kind") == CHANGED] == []


@pytest.mark.parametrize("check_s", [-1.0, float("nan"), "1"])
def test_a_check_interval_that_is_no_duration_is_refused_naming_it(check_s: object) -> None:
    with pytest.raises(InvalidInputError, match="check_s"):
        MBTilesStore(STORE, check_s=check_s)  # type: ignore[arg-type]
