"""A damaged map is reported as one: when a store's tiles fail their sha256, ``replay`` and
``eval`` count the dropped candidates by why they were dropped, each frame's line in
``results.jsonl`` names its dropped candidates and why, ``report.html`` says so too, and the
hint of a run where no frame matched names the tile store, not the heights and attitudes (two
frames, ``sift_magsac``)."""

from __future__ import annotations

import contextlib
import html
import json
import sqlite3
import subprocess
from collections.abc import Callable
from pathlib import Path

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
C3 = Callable[..., subprocess.CompletedProcess[str]]
CAUSE = "tile_decode TileDigestError"


def _corrupt_every_tile(store: Path) -> None:
    """One byte of every tile flipped, its recorded sha256 left as it was."""
    with contextlib.closing(sqlite3.connect(store)) as db:
        for rowid, data in db.execute("select rowid, tile_data from tiles").fetchall():
            damaged = bytearray(data)
            damaged[len(damaged) // 2] ^= 0xFF
            db.execute("update tiles set tile_data=? where rowid=?", (bytes(damaged), rowid))
        db.commit()


def test_a_replay_on_a_damaged_store_says_the_candidates_were_dropped_for_their_tiles(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("damaged")
    store = flight / "tiles.mbtiles"
    _corrupt_every_tile(store)
    out = tmp_path / "out"
    proc = c3("replay", str(flight), "--strategy", "sift_magsac", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    results = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    dropped = [d for r in results for d in r["dropped"]]
    assert len(dropped) == 6 and all(d["cause"] == CAUSE for d in dropped), dropped
    assert all("sha256 mismatch" in d["reason"] for d in dropped), dropped
    assert [d["candidate_index"] for d in results[0]["dropped"]] == [0, 1, 2]
    report = json.loads((out / "report.json").read_text())
    assert report["candidates_dropped"] == {CAUSE: 6}
    assert f"  candidates dropped 6 of 6: {CAUSE} 6" in proc.stdout.splitlines(), proc.stdout
    assert f"the tile store {store}" in proc.stdout, proc.stdout
    assert "heights and attitudes" not in proc.stdout, proc.stdout
    page = html.unescape((out / "report.html").read_text())  # the flight report says it too
    assert f"candidates dropped 6 of 6: {CAUSE} 6" in page
    assert f"the tile store {store} is damaged" in page


def test_an_eval_on_a_damaged_store_counts_the_dropped_candidates(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("damaged")
    _corrupt_every_tile(flight / "tiles.mbtiles")
    out = tmp_path / "ev"
    proc = c3("eval", str(flight), "--strategy", "sift_magsac", "--no-baseline", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    line = f"sift_magsac: candidates dropped 6 of 6: {CAUSE} 6"
    assert line in proc.stdout.splitlines(), proc.stdout
    assert f"the tile store {flight / 'tiles.mbtiles'}" in proc.stdout, proc.stdout


def test_a_replay_on_an_intact_store_blames_no_tile(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    flight = small_flight("intact")
    out = tmp_path / "out"
    proc = c3("replay", str(flight), "--strategy", "sift_magsac", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "tile store" not in proc.stdout, proc.stdout
    results = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    causes = [d["cause"] for r in results for d in r["dropped"]]
    assert CAUSE not in causes
    assert "is damaged" not in (out / "report.html").read_text()
    counted = json.loads((out / "report.json").read_text())["candidates_dropped"]
    assert counted == {cause: causes.count(cause) for cause in causes}
