"""``tiles info`` of an SQLite file whose ``tiles`` or ``metadata`` table is not MBTiles-shaped
(other column names; a zoom_level, tile_column or tile_row that is NULL, text or a negative
zoom) is bad input: exit 2, one line naming the file and what is wrong (it was "internal error",
exit 1, or "not an SQLite database" for a metadata table with other columns)."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
STORE = REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles"

CASES = [
    (
        "DROP TABLE tiles; CREATE TABLE tiles (z INTEGER, x INTEGER, y INTEGER, data BLOB);",
        "its tiles table lacks the columns",
    ),
    (
        "DROP TABLE metadata; CREATE TABLE metadata (k TEXT, v TEXT);",
        "its metadata table lacks the columns ['name', 'value']",
    ),
    ("INSERT INTO tiles VALUES ('abc', 0, 0, X'00');", "a zoom_level of 'abc'"),
    ("DROP INDEX tile_index; INSERT INTO tiles VALUES (NULL, 0, 0, X'00');", "zoom_level of NULL"),
    ("INSERT INTO tiles VALUES (-1, 0, 0, X'00');", "a zoom_level of -1"),
    ("INSERT INTO tiles VALUES (15, 'abc', 0, X'00');", "a tile_column of 'abc'"),
    ("DROP INDEX tile_index; INSERT INTO tiles VALUES (15, 0, NULL, X'00');", "tile_row of NULL"),
]


@pytest.mark.parametrize(("sql", "said"), CASES)
def test_tiles_info_refuses_a_store_not_mbtiles_shaped_in_one_line_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], sql: str, said: str
) -> None:
    from c3_matcher.cli import main

    path = tmp_path / "odd.mbtiles"
    shutil.copy(STORE, path)
    db = sqlite3.connect(path)
    db.executescript(sql)
    db.commit()
    db.close()
    capsys.readouterr()
    for argv in (["tiles", "info", str(path)], ["tiles", "info", str(path), "--json"]):
        assert main(argv) == 2
        out, err = capsys.readouterr()
        assert out == "" and len(err.strip().splitlines()) == 1, err
        line = err.strip()
        assert line.startswith(f"c3-matcher: mbtiles: {path}: not an MBTiles file ("), line
        assert said in line and "internal error" not in line, line
