"""``tiles digest`` and ``tiles info`` on stores as other tools write them, from the shipped demo
store: a blank tile stored as 0 bytes gets no digest and is counted with no data (as NULL is),
``tiles info`` shows the tile size, and refuses in one line, exit 2, a store of 512-px tiles
(naming their size) and a gdal2tiles TMS folder given as an XYZ folder (naming what it holds)."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.tilestore.writer import add_missing_digests

REPO = Path(__file__).resolve().parents[3]
STORE = REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
TILE = REPO / "data" / "demo" / "tile_a.png"


def _store(tmp_path: Path, *sql: str) -> Path:
    path = tmp_path / "s.mbtiles"
    shutil.copy(STORE, path)
    db = sqlite3.connect(path)
    db.executescript(";".join(sql))
    db.commit()
    db.close()
    return path


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    from c3_matcher.cli import main

    capsys.readouterr()
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_tiles_digest_gives_a_zero_byte_tile_no_digest_and_counts_it_with_no_data(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It was digested (sha256 of 0 bytes) as a tile, which the flight then failed to decode."""
    path = _store(
        tmp_path,
        "DROP TABLE c3_tile_digest",
        "UPDATE tiles SET tile_data = x'' WHERE rowid <= 3",
        "UPDATE tiles SET tile_data = NULL WHERE rowid BETWEEN 4 AND 5",
    )
    (tiles,) = sqlite3.connect(path).execute("SELECT count(*) FROM tiles").fetchone()
    done = add_missing_digests(path)
    assert (done.tiles, done.added, done.kept, done.empty) == (tiles, tiles - 5, 0, 5)
    db = sqlite3.connect(path)
    blank = "SELECT count(*) FROM c3_tile_digest d JOIN tiles t USING (zoom_level, tile_column,"
    blank += " tile_row) WHERE length(t.tile_data) = 0"
    assert db.execute(blank).fetchone() == (0,)
    keys = db.execute("SELECT zoom_level, tile_column, tile_row FROM tiles WHERE rowid <= 5")
    with MBTilesStore(path) as store:
        for z, x, row in keys.fetchall():
            assert store.tile_bytes(z, x, (1 << z) - 1 - row) is None
    code, out, _ = _run(capsys, "tiles", "digest", str(path))
    assert code == 0 and "5 with no data (NULL or 0 bytes: no tile to a flight)" in out, out


def test_tiles_info_shows_the_tile_size(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = _run(capsys, "tiles", "info", str(STORE), "--json")
    assert code == 0, err
    assert json.loads(out)["tile_px"] == [256, 256]
    code, out, _ = _run(capsys, "tiles", "info", str(STORE))
    assert code == 0 and "\n  tile size: 256x256 px\n" in out, out


def test_tiles_info_refuses_a_store_of_512_px_tiles_in_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It was described as any store, and then every window of it failed in a match."""
    path = _store(tmp_path, "DROP TABLE c3_tile_digest")
    db = sqlite3.connect(path)
    for rowid, blob in db.execute("SELECT rowid, tile_data FROM tiles").fetchall():
        image = cv2.imdecode(np.frombuffer(blob, np.uint8), cv2.IMREAD_COLOR)
        ok, buf = cv2.imencode(".jpg", cv2.resize(image, (512, 512)))
        assert ok
        db.execute("UPDATE tiles SET tile_data=? WHERE rowid=?", (buf.tobytes(), rowid))
    db.commit()
    db.close()
    code, out, err = _run(capsys, "tiles", "info", str(path))
    assert (code, out) == (2, "") and len(err.strip().splitlines()) == 1, err
    assert f"{path}: its tiles are 512x512 px" in err and "256-px web-mercator" in err, err


def test_tiles_info_refuses_a_tms_folder_naming_its_tilemapresource(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = tmp_path / "tms"
    (root / "15" / "7358").mkdir(parents=True)
    shutil.copy(TILE, root / "15" / "7358" / "21247.png")
    (root / "tilemapresource.xml").write_text('<TileMap version="1.0.0"/>')
    code, out, err = _run(capsys, "tiles", "info", str(root))
    assert (code, out) == (2, "") and len(err.strip().splitlines()) == 1, err
    assert "holds tilemapresource.xml, so it is a TMS tile folder" in err, err
