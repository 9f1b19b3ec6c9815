"""Ambiguity on the real path (real engines, the shipped frame and its true window of the demo
store): the same picture named as two places a kilometre apart (what texture repeating at one
orientation and scale gives: two tiles that match alike) is no fix, exit 3 with
``AmbiguousMatchError`` and the record naming both; the same picture twice at one place, and the
true window with the shipped distractor, are fixes as before."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from c3_matcher.dto import TileId
from c3_matcher.fdr import read_fdr
from c3_matcher.tilestore.handles import MosaicTileHandle
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[1]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
FRAME = json.loads((FLIGHT / "frames.jsonl").read_text().splitlines()[0])
TRUE = next(c for c in FRAME["candidates"] if c["is_true"])
OTHER = next(c for c in FRAME["candidates"] if not c["is_true"])
WINDOW = 448


def _window(tmp_path: Path, candidate: dict[str, object]) -> Path:
    """The store's window around ``candidate``'s id, as a PNG file."""
    tile_id = [float(v) for v in candidate["tile_id"]]  # type: ignore[attr-defined]
    store = MBTilesStore(FLIGHT / "tiles.mbtiles")
    try:
        handle = MosaicTileHandle(store, TileId(int(tile_id[0]), *tile_id[1:]), WINDOW)
        path = tmp_path / f"{_id(tile_id)}.png"
        path.write_bytes(bytes(handle.encoded()))
    finally:
        store.close()
    return path


def _match(
    tmp_path: Path, engine_dir: Path, tiles: list[tuple[Path, list[float]]]
) -> subprocess.CompletedProcess[str]:
    roll, pitch, yaw = FRAME["attitude_deg"]
    named = [w for path, tile_id in tiles for w in ("--tile", str(path), "--tile-id", _id(tile_id))]
    return run_cli(
        *("match", "--query", str(FLIGHT / FRAME["image"])),
        *("--calibration", str(FLIGHT / "calibration.json")),
        *("--attitude", f"{roll},{pitch},{yaw}", "--height", str(FRAME["height_m"])),
        *("--no-correspondences", *named),
        cwd=tmp_path,
        engine_dir=engine_dir,
        settings={"C3_MATCHER_FDR__PATH": str(tmp_path / "fdr.jsonl")},
    )


def _id(tile_id: list[float]) -> str:
    return ",".join(map(str, tile_id))


@pytest.mark.slow
def test_one_picture_at_two_places_is_no_fix(tmp_path: Path, engine_dir: Path) -> None:
    picture = _window(tmp_path, TRUE)
    zoom, lat, lon = TRUE["tile_id"]
    elsewhere = [zoom, lat + 0.01, lon]  # 1.1 km north
    proc = _match(tmp_path, engine_dir, [(picture, TRUE["tile_id"]), (picture, elsewhere)])
    assert proc.returncode == 3, proc.stderr[-2000:]
    out = json.loads(proc.stdout)
    assert out["error"] == "AmbiguousMatchError", out
    assert "places the frame 11" in out["message"] and " m from candidate 0" in out["message"]
    assert out["ambiguous"].startswith("candidate 1 (")
    records = [
        r for r in read_fdr(tmp_path / "fdr.jsonl") if r["kind"] == "matcher.insufficient_inliers"
    ]
    (said,) = [r["payload"]["ambiguous"] for r in records]
    assert said["best_index"] == 0 and said["rival_index"] == 1
    assert 1000 < said["distance_m"] < 1250


@pytest.mark.slow
def test_one_picture_at_one_place_and_the_true_window_with_a_distractor_are_fixes(
    tmp_path: Path, engine_dir: Path
) -> None:
    picture, other = _window(tmp_path, TRUE), _window(tmp_path, OTHER)
    for tiles in (
        [(picture, TRUE["tile_id"]), (picture, TRUE["tile_id"])],
        [(picture, TRUE["tile_id"]), (other, OTHER["tile_id"])],
    ):
        proc = _match(tmp_path, engine_dir, tiles)
        assert proc.returncode == 0, proc.stderr[-2000:]
        best = json.loads(proc.stdout)["per_candidate"][0]
        assert best["tile_id"] == TRUE["tile_id"] and best["inlier_count"] >= 300
