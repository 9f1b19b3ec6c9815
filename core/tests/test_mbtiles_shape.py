"""An SQLite file whose ``tiles`` or ``metadata`` table is not MBTiles-shaped (other column
names, a zoom_level that is NULL, text or negative) is refused when the store is opened, as bad
input naming the file and what is wrong: ``match --store`` exits 2 with one line (it was
"internal error", exit 1, and a ``metadata`` table with other columns was called "not an SQLite
database"). The columns are checked once, at open: a read runs only its own query."""

from __future__ import annotations

import os
import shutil
import sqlite3
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.mbtiles import MBTilesStore

REPO = Path(__file__).resolve().parents[2]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
STORE = FLIGHT / "tiles.mbtiles"


def _other_tile_columns(db: sqlite3.Connection) -> None:
    db.execute("DROP TABLE tiles")
    db.execute("CREATE TABLE tiles (z INTEGER, x INTEGER, y INTEGER, data BLOB)")


def _other_metadata_columns(db: sqlite3.Connection) -> None:
    db.execute("DROP TABLE metadata")
    db.execute("CREATE TABLE metadata (k TEXT, v TEXT)")


def _row_at_zoom(zoom: object) -> Callable[[sqlite3.Connection], None]:
    def change(db: sqlite3.Connection) -> None:
        db.execute("DROP INDEX IF EXISTS tile_index")
        db.execute("INSERT INTO tiles VALUES (?, 0, 0, X'00')", (zoom,))

    return change


# (name, change, what the one line says beside "not an MBTiles file")
CASES = [
    (
        "tilecols",
        _other_tile_columns,
        "its tiles table lacks the columns ['zoom_level', 'tile_column', 'tile_row', 'tile_data'];"
        " it has ['z', 'x', 'y', 'data']",
    ),
    (
        "metacols",
        _other_metadata_columns,
        "its metadata table lacks the columns ['name', 'value']; it has ['k', 'v']",
    ),
    ("textzoom", _row_at_zoom("abc"), "its tiles table holds a zoom_level of 'abc'"),
    ("nullzoom", _row_at_zoom(None), "its tiles table holds a zoom_level of NULL"),
    ("negzoom", _row_at_zoom(-1), "its tiles table holds a zoom_level of -1"),
]


def _store(tmp_path: Path, name: str, change: Callable[[sqlite3.Connection], None]) -> Path:
    path = tmp_path / f"{name}.mbtiles"
    shutil.copy(STORE, path)
    db = sqlite3.connect(path)
    change(db)
    db.commit()
    db.close()
    return path


@pytest.mark.parametrize(("name", "change", "said"), CASES, ids=[c[0] for c in CASES])
def test_a_store_not_mbtiles_shaped_is_refused_at_open_naming_what_is_wrong(
    tmp_path: Path, name: str, change: Callable[[sqlite3.Connection], None], said: str
) -> None:
    path = _store(tmp_path, name, change)
    with pytest.raises(InvalidInputError) as refused:
        MBTilesStore(path)
    assert str(refused.value).startswith(f"mbtiles: {path}: not an MBTiles file ({said}")
    assert "not an SQLite database" not in str(refused.value)


@pytest.mark.parametrize(("name", "change", "said"), CASES, ids=[c[0] for c in CASES])
def test_match_store_refuses_a_store_not_mbtiles_shaped_in_one_line_exit_2(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    name: str,
    change: Callable[[sqlite3.Connection], None],
    said: str,
) -> None:
    from c3_matcher.cli import main

    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)
    monkeypatch.setenv("C3_MATCHER_FDR__PATH", str(tmp_path / "fdr.jsonl"))
    path = _store(tmp_path, name, change)
    argv = ["match", "--query", str(FLIGHT / "frames" / "000000.jpg")]
    argv += ["--calibration", str(FLIGHT / "calibration.json"), "--store", str(path)]
    argv += ["--tile-id", "15,47.02707824931894,-99.151611328125", "--height", "780"]
    capsys.readouterr()
    assert main(argv) == 2
    out, err = capsys.readouterr()
    lines = [x for x in err.splitlines() if not x.startswith(("{", "c3-matcher match: warning"))]
    assert out == "" and len(lines) == 1, err
    assert lines[0].startswith(f"c3-matcher: --store {path}: ") and said in lines[0], err


def test_an_mbtiles_store_and_a_tiles_view_open_as_before(tmp_path: Path) -> None:
    view = tmp_path / "view.mbtiles"
    shutil.copy(STORE, view)
    db = sqlite3.connect(view)
    db.execute("ALTER TABLE tiles RENAME TO stored")
    db.execute(
        "CREATE VIEW tiles AS SELECT zoom_level, tile_column, tile_row, tile_data FROM stored"
    )
    db.commit()
    db.close()
    for path in (STORE, view):
        with MBTilesStore(path) as store:
            assert store.zooms() == [15] and len(list(store.tiles(15))) == 35
            assert store.metadata["format"] in ("png", "jpg")


def test_the_columns_are_checked_at_open_not_by_each_read() -> None:
    with MBTilesStore(STORE) as store:
        x, y = next(iter(store.tiles(15)))
        said: list[str] = []
        store._db.set_trace_callback(said.append)
        for _ in range(3):
            assert store.tile_bytes(15, x, y) is not None
        assert len(said) == 3 and all(s.lstrip().startswith("SELECT t.tile_data") for s in said)


@pytest.mark.parametrize(
    ("sql", "said"),
    [
        ("INSERT INTO tiles VALUES (15.5, 0, 0, X'00'), (16, 0, 0, X'00')", "zoom_level of 15.5"),
        ("INSERT INTO tiles VALUES (15, 'abc', 0, X'00')", "a tile_column of 'abc'"),
        ("INSERT INTO tiles VALUES (15, 0, NULL, X'00')", "a tile_row of NULL"),
    ],
)
def test_a_value_not_an_integer_among_the_rows_is_bad_input_when_listed(
    tmp_path: Path, sql: str, said: str
) -> None:
    """What the check at open does not look at (a tile's column or row; a zoom between the
    smallest and the largest) is refused, naming the store, where the rows are listed."""
    path = _store(tmp_path, "odd", lambda db: db.executescript(f"DROP INDEX tile_index; {sql};"))
    with pytest.raises(InvalidInputError) as refused, MBTilesStore(path) as store:
        for zoom in store.zooms():
            list(store.tiles(zoom))
    assert str(refused.value).startswith(f"mbtiles: {path}: not an MBTiles file (")
    assert said in str(refused.value)


def test_a_store_of_untyped_columns_holding_whole_numbers_as_reals_opens_as_before(
    tmp_path: Path,
) -> None:
    """A store whose tiles table was made without column types, its numbers written as 15.0
    (another tool's store): read as it was before the shape check, never refused."""

    def untyped_reals(db: sqlite3.Connection) -> None:
        db.executescript(
            "ALTER TABLE tiles RENAME TO typed;"
            "CREATE TABLE tiles (zoom_level, tile_column, tile_row, tile_data);"
            "INSERT INTO tiles SELECT zoom_level * 1.0, tile_column * 1.0, tile_row * 1.0,"
            " tile_data FROM typed;"
            "DROP TABLE typed;"
        )

    path = _store(tmp_path, "untyped", untyped_reals)
    with MBTilesStore(STORE) as typed, MBTilesStore(path) as store:
        assert store.zooms() == [15] and all(type(z) is int for z in store.zooms())
        tiles = list(store.tiles(15))
        assert tiles == list(typed.tiles(15)) and all(type(x) is int for x, _ in tiles)
        x, y = tiles[0]
        assert store.tile_bytes(15, x, y) == typed.tile_bytes(15, x, y)
