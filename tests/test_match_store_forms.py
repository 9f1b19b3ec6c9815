"""``c3-matcher match --store`` on the demo flight's store as other tools write it (real engines,
the shipped frame): rows counted from the north (metadata ``scheme`` ``xyz``) find the true
window as the shipped store does; a column of blank tiles stored as 0 bytes is nodata, as NULL
is, so the window over it still matches; a store of 512-px tiles is one line, exit 2."""

from __future__ import annotations

import contextlib
import json
import math
import shutil
import sqlite3
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[1]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
FRAME = json.loads((FLIGHT / "frames.jsonl").read_text().splitlines()[0])
STORE = FLIGHT / "tiles.mbtiles"
TRUE = next(c for c in FRAME["candidates"] if c["is_true"])
OTHER = next(c for c in FRAME["candidates"] if not c["is_true"])


def _store(tmp_path: Path, name: str, *sql: tuple[str, tuple[object, ...]]) -> Path:
    path = tmp_path / name
    shutil.copy(STORE, path)
    db = sqlite3.connect(path)
    db.execute("DROP TABLE c3_tile_digest")
    for statement, args in sql:
        db.execute(statement, args)
    db.commit()
    db.close()
    return path


def _match(tmp_path: Path, engine_dir: Path, store: Path) -> subprocess.CompletedProcess[str]:
    roll, pitch, yaw = FRAME["attitude_deg"]
    tile_ids = [",".join(map(str, c["tile_id"])) for c in (TRUE, OTHER)]
    return run_cli(
        *("match", "--query", str(FLIGHT / FRAME["image"])),
        *("--calibration", str(FLIGHT / "calibration.json")),
        *("--attitude", f"{roll},{pitch},{yaw}", "--height", str(FRAME["height_m"])),
        *("--store", str(store), "--window", "448", "--no-correspondences"),
        *("--tile-id", tile_ids[0], "--tile-id", tile_ids[1]),
        cwd=tmp_path,
        engine_dir=engine_dir,
        settings={"C3_MATCHER_FDR__PATH": str(tmp_path / "fdr.jsonl")},
    )


def _found(proc: subprocess.CompletedProcess[str]) -> tuple[object, ...]:
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout)
    best = out["per_candidate"][0]
    assert best["tile_index"] == 0 and best["tile_id"] == TRUE["tile_id"], out
    candidates = [(c["tile_index"], c["inlier_count"]) for c in out["per_candidate"]]
    return tuple(candidates), out["centre_lat"], out["centre_lon"]


def test_a_store_whose_rows_count_from_the_north_finds_the_true_window(
    engine_dir: Path, tmp_path: Path
) -> None:
    """Its rows were read as TMS rows: "no stored tile overlaps this window" for every one."""
    xyz = _store(
        tmp_path,
        "xyz.mbtiles",
        ("UPDATE tiles SET tile_row = -1 - ((1 << zoom_level) - 1 - tile_row)", ()),
        ("UPDATE tiles SET tile_row = -1 - tile_row", ()),
        ("INSERT INTO metadata VALUES ('scheme', 'xyz')", ()),
    )
    found = _found(_match(tmp_path, engine_dir, xyz))
    assert found == _found(_match(tmp_path, engine_dir, STORE))
    assert found[0][0][1] >= 80  # type: ignore[index]


def test_a_column_of_zero_byte_tiles_is_nodata_as_null_tiles_are(
    engine_dir: Path, tmp_path: Path
) -> None:
    """Blank tiles stored as 0 bytes were "no bytes to decode", which dropped the true window
    (it covers the blanked column) and failed the frame; NULL ones were nodata, as now both."""
    zoom, _, lon = TRUE["tile_id"]
    column = math.floor((lon + 180.0) / 360.0 * 2**zoom) - 1  # the west half of the true window
    blank = "UPDATE tiles SET tile_data = {} WHERE zoom_level = ? AND tile_column = ?"
    empty = _store(tmp_path, "empty.mbtiles", (blank.format("x''"), (zoom, column)))
    null = _store(tmp_path, "null.mbtiles", (blank.format("NULL"), (zoom, column)))
    (count,) = (
        sqlite3.connect(empty)
        .execute("SELECT count(*) FROM tiles WHERE length(tile_data) = 0")
        .fetchone()
    )
    assert count >= 3
    assert _found(_match(tmp_path, engine_dir, empty)) == _found(_match(tmp_path, engine_dir, null))


@pytest.mark.parametrize("px", [512])
def test_a_store_of_tiles_not_256_px_is_one_line_and_exit_2(
    engine_dir: Path, tmp_path: Path, px: int
) -> None:
    """It was opened, and then every window failed "expected 256x256 px" (exit 3)."""
    path = _store(tmp_path, "retina.mbtiles")

    def resized(blob: bytes) -> bytes:
        image = cv2.imdecode(np.frombuffer(blob, np.uint8), cv2.IMREAD_COLOR)
        return cv2.imencode(".jpg", cv2.resize(image, (px, px)))[1].tobytes()

    with contextlib.closing(sqlite3.connect(path)) as db, db:
        rows = db.execute("SELECT rowid, tile_data FROM tiles").fetchall()
        db.executemany(
            "UPDATE tiles SET tile_data = ? WHERE rowid = ?", [(resized(b), r) for r, b in rows]
        )
    proc = _match(tmp_path, engine_dir, path)
    assert proc.returncode == 2, proc.stderr[-2000:]
    line = proc.stderr.strip().splitlines()[-1]
    assert f"--store {path}" in line and f"its tiles are {px}x{px} px" in line, line
