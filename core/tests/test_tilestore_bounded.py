"""A store file whose tables are views that never end (MBTiles allows ``tiles`` to be a view)
never hangs the process: the read at open is refused within ``OPEN_S``, a tile's read fails as
that tile's error within ``READ_S``, a sidecar that never answers is unavailable or damaged, and
Ctrl-C or SIGTERM stops a query that runs on (a listing, which has no bound). Each case runs in
a child process with a timeout, so that a hang fails the test instead of hanging pytest."""

from __future__ import annotations

import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

from c3_matcher.tilestore.bounded import OPEN_S, READ_S

_NEVER = "(WITH RECURSIVE n(i) AS (SELECT 0 UNION ALL SELECT i + 1 FROM n) SELECT i FROM n {})"
ENDLESS = _NEVER.format("WHERE i < 0 LIMIT 1")  # a scalar that is never found
MARGIN_S = 10.0  # a loaded machine's start-up of a child Python, and its imports
SLACK_S = 2.0  # past a bound, until a loaded machine's progress handler next runs


def _store(path: Path, tiles_view: str) -> Path:
    """An MBTiles file at ``path`` whose metadata is a table and whose ``tiles`` is the view
    ``tiles_view`` (it may read the table ``t``: zoom 15, tiles at columns 0 and 1, row 0)."""
    db = sqlite3.connect(path)
    db.execute("CREATE TABLE metadata (name TEXT, value TEXT)")
    db.executemany(
        "INSERT INTO metadata VALUES (?, ?)",
        [("name", "x"), ("format", "png"), ("minzoom", "15"), ("maxzoom", "15")],
    )
    db.execute("CREATE TABLE t (zoom_level, tile_column, tile_row, tile_data)")
    db.execute("CREATE UNIQUE INDEX t_index ON t (zoom_level, tile_column, tile_row)")
    db.executemany("INSERT INTO t VALUES (15, ?, 0, x'00')", [(0,), (1,)])
    db.execute(f"CREATE VIEW tiles AS {tiles_view}")
    db.commit()
    db.close()
    return path


def _child(script: str, *args: str, timeout: float) -> tuple[str, float]:
    """``script`` run by a child Python with ``args``: its stdout and how long it ran; fails
    (not hangs) when it runs past ``timeout``, or fails."""
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout, time.monotonic() - started


def test_a_recursive_view_store_is_refused_at_open_within_the_bound(tmp_path: Path) -> None:
    path = _store(
        tmp_path / "slow.mbtiles",
        "WITH RECURSIVE n(i) AS (SELECT 0 UNION ALL SELECT i + 1 FROM n) "
        "SELECT 15 AS zoom_level, i AS tile_column, i AS tile_row, x'00' AS tile_data FROM n",
    )
    out, _ = _child(
        """
        import sys, time
        from c3_matcher.errors import InvalidInputError
        from c3_matcher.tilestore.mbtiles import MBTilesStore
        started = time.monotonic()
        try:
            MBTilesStore(sys.argv[1])
        except InvalidInputError as exc:
            print(f"{time.monotonic() - started:.3f}", exc)
        """,
        str(path),
        timeout=OPEN_S + MARGIN_S,
    )
    seconds, said = out.split(" ", 1)
    assert OPEN_S <= float(seconds) < OPEN_S + SLACK_S, out
    assert str(path) in said and f"took longer than {OPEN_S:g} s" in said, said


def test_a_tile_whose_read_never_ends_is_that_tiles_error_within_the_bound(
    tmp_path: Path,
) -> None:
    """The view answers the checks at open (no tile_data is read) and every tile but one."""
    data = f"CASE WHEN tile_column = 1 THEN {ENDLESS} ELSE tile_data END"
    path = _store(
        tmp_path / "tiles.mbtiles",
        f"SELECT zoom_level, tile_column, tile_row, {data} AS tile_data FROM t",
    )
    out, _ = _child(
        """
        import sys, time
        from c3_matcher.errors import InvalidInputError
        from c3_matcher.tilestore.mbtiles import MBTilesStore, TileStoreUnusableError
        with MBTilesStore(sys.argv[1]) as store:
            assert store.zooms() == [15] and sorted(store.tiles(15)) == [(0, 32767), (1, 32767)]
            started = time.monotonic()
            try:
                store.tile_bytes(15, 1, 32767)
            except TileStoreUnusableError as exc:
                raise AssertionError(f"one tile's fault taken for the store's: {exc}")
            except InvalidInputError as exc:
                print(f"{time.monotonic() - started:.3f}", exc)
            assert bytes(store.tile_bytes(15, 0, 32767)) == b"\\x00"  # the others are served
        """,
        str(path),
        timeout=OPEN_S + MARGIN_S,
    )
    seconds, said = out.split(" ", 1)
    assert READ_S <= float(seconds) < READ_S + SLACK_S, out
    assert "tile 15/1/32767" in said and f"took longer than {READ_S:g} s" in said, said


def test_a_sidecar_whose_sets_never_end_is_unavailable_in_flight_and_damaged_to_the_writer(
    tmp_path: Path,
) -> None:
    from c3_matcher.tilestore.sidecar import _SET_COLUMNS

    path = tmp_path / "tiles.mbtiles.features.sqlite"
    db = sqlite3.connect(path)
    columns = ", ".join(f"{ENDLESS} AS {c}" for c in (*_SET_COLUMNS.split(", "), "created"))
    db.execute(f"CREATE VIEW window_sets AS SELECT {columns}")
    db.close()
    out, _ = _child(
        """
        import sys
        from c3_matcher.tilestore.sidecar import MapFeatureStore
        from c3_matcher.tilestore.sidecar_errors import (
            FeatureStoreUnavailableError, SidecarDamagedError)
        side = MapFeatureStore(sys.argv[1])
        try:
            side.feature_set("ab" * 32)
        except FeatureStoreUnavailableError as exc:
            print("flight:", exc)
        assert side.feature_set("ab" * 32) is None  # within the outage: nothing, at once
        side.close()
        try:
            MapFeatureStore(sys.argv[1], writable=True)
        except SidecarDamagedError as exc:
            print("writer:", exc)
        """,
        str(path),
        timeout=READ_S + OPEN_S + MARGIN_S,
    )
    flight, writer = out.splitlines()
    assert flight.startswith("flight:") and f"took longer than {READ_S:g} s" in flight, out
    assert writer.startswith("writer:") and f"took longer than {OPEN_S:g} s" in writer, out


def test_sigterm_and_ctrl_c_stop_a_listing_that_never_ends(tmp_path: Path) -> None:
    """``tiles info`` of a store whose tiles answer every check but whose listing never ends
    (a listing has no bound: a store's may be long) ends on SIGTERM and Ctrl-C, as a shell
    reports them (143, 130)."""
    path = _store(
        tmp_path / "tiles.mbtiles",
        f"SELECT zoom_level, {ENDLESS} AS tile_column, tile_row, tile_data FROM t",
    )
    main = (
        "import sys; from c3_matcher.cli import main; "
        "print('imported', file=sys.stderr, flush=True); sys.exit(main(sys.argv[1:]))"
    )
    for signum, status in ((signal.SIGTERM, 143), (signal.SIGINT, 130)):
        child = subprocess.Popen(
            [sys.executable, "-c", main, "tiles", "info", str(path)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            assert child.stderr is not None
            assert child.stderr.readline() == "imported\n"  # however long start-up took
            time.sleep(2.0)  # the store opened (milliseconds): in the listing
            assert child.poll() is None, child.communicate()
            child.send_signal(signum)
            _, err = child.communicate(timeout=5)
        finally:
            child.kill()
            child.wait()
        assert child.returncode == status, err


def test_a_running_store_waits_on_a_never_ending_replacement_at_most_one_read_bound(
    tmp_path: Path,
) -> None:
    """A store file replaced under a running store by one whose tables never answer: the frame
    that looks at it waits ``READ_S`` (not ``OPEN_S``), and later reads do not look again
    until the file changes again."""
    good = _store(tmp_path / "good.mbtiles", "SELECT * FROM t")
    endless = _store(
        tmp_path / "endless.mbtiles",
        "WITH RECURSIVE n(i) AS (SELECT 0 UNION ALL SELECT i + 1 FROM n) "
        "SELECT 15 AS zoom_level, i AS tile_column, i AS tile_row, x'00' AS tile_data FROM n",
    )
    out, _ = _child(
        """
        import os, sys, time
        from c3_matcher.errors import InvalidInputError
        from c3_matcher.tilestore.mbtiles import MBTilesStore
        store = MBTilesStore(sys.argv[1], check_s=0.0)
        assert bytes(store.tile_bytes(15, 0, 32767)) == b"\\x00"
        os.replace(sys.argv[2], sys.argv[1])
        for _ in range(3):
            started = time.monotonic()
            try:
                store.tile_bytes(15, 0, 32767)
            except InvalidInputError:
                pass
            print(f"{time.monotonic() - started:.3f}")
        store.close()
        """,
        str(good),
        str(endless),
        timeout=OPEN_S + MARGIN_S,
    )
    first, *later = (float(s) for s in out.split())
    # the look, the read, the store's probe, each within READ_S (1.5 s), well below OPEN_S (5 s)
    assert first < 3 * READ_S + SLACK_S < OPEN_S, out
    assert all(s < 2 * READ_S + SLACK_S for s in later), out  # no look again: the file as read
