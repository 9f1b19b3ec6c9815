"""``c3-matcher match --store``: a frame against windows of the user's own MBTiles map, read
through the flight's tile-store path (real engines, the shipped demo flight's frame and store);
a store, tile id or output that cannot serve is one line and exit 2."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import pytest

from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run.scoring import truth_position
from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[1]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
FRAME = json.loads((FLIGHT / "frames.jsonl").read_text().splitlines()[0])
STORE = FLIGHT / "tiles.mbtiles"
TILE = REPO / "data" / "demo" / "tile_a.png"


def _match(tmp_path: Path, engine_dir: Path, *args: str) -> subprocess.CompletedProcess[str]:
    settings = {"C3_MATCHER_FDR__PATH": str(tmp_path / "fdr.jsonl")}
    query = ["match", "--query", str(FLIGHT / FRAME["image"])]
    return run_cli(*query, *args, cwd=tmp_path, engine_dir=engine_dir, settings=settings)


def _tile_id(candidate: dict[str, object]) -> str:
    return ",".join(map(str, candidate["tile_id"]))  # type: ignore[call-overload]


def test_a_frame_against_windows_of_a_store_finds_its_own(engine_dir, tmp_path):
    """The true window wins; a window over no stored tile (off the map) is dropped as in
    flight and named in the JSON with why, and the fix and the picture are still given."""
    true, other = sorted(FRAME["candidates"], key=lambda c: not c["is_true"])[:2]
    zoom, lat, lon = true["tile_id"]
    off_map = f"{zoom},{lat},{lon + 0.5}"  # ~40 km east of the store's map
    roll, pitch, yaw = FRAME["attitude_deg"]
    proc = _match(
        tmp_path,
        engine_dir,
        *("--calibration", str(FLIGHT / "calibration.json")),
        *("--attitude", f"{roll},{pitch},{yaw}", "--height", str(FRAME["height_m"])),
        *("--store", str(STORE), "--window", "448"),
        *("--tile-id", _tile_id(other), "--tile-id", _tile_id(true), "--tile-id", off_map),
        *("--viz", str(tmp_path / "match.png"), "--no-correspondences"),
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout)
    best = out["per_candidate"][0]
    assert best["tile_index"] == 1 and best["tile_id"] == true["tile_id"]
    assert best["inlier_count"] >= 80
    dataset = load_dataset(FLIGHT)  # where the frame's principal point truly looks
    truth = truth_position(dataset, dataset.frames[0])
    assert truth is not None
    north = (out["centre_lat"] - truth[0]) * 111_320.0
    east = (out["centre_lon"] - truth[1]) * 111_320.0 * math.cos(math.radians(truth[0]))
    assert math.hypot(north, east) < 3.0  # m; the pose's footprint centre is 28 m off
    (dropped,) = (d for d in out["dropped"] if d["tile_index"] == 2)
    assert "no stored tile overlaps" in dropped["reason"], dropped
    assert (tmp_path / "match.png").stat().st_size > 10_000
    records = [json.loads(x) for x in (tmp_path / "fdr.jsonl").read_text().splitlines()]
    (done,) = (r["payload"] for r in records if r["kind"] == "matcher.frame_done")
    assert done["candidates_input"] == 3


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--store", str(STORE)], "--tile-id: --store needs one --tile-id per candidate window"),
        (["--store", str(STORE), "--tile-id", "14,47.02,-99.15"], "has no tiles at zoom 14"),
        (["--store", str(REPO / "README.md"), "--tile-id", "15,47,-99"], "--store"),
        (["--store", "missing.mbtiles", "--tile-id", "15,47,-99"], "--store missing.mbtiles"),
        (["--store", str(STORE), "--tile", str(STORE)], "not allowed with argument --store"),
        (["--store", str(STORE), "--tile-id", "15,47,-99", "--fdr", str(STORE)], "--fdr"),
        (["--store", str(STORE), "--tile-id", "15,47,-99", "--window", "8"], "--window"),
        (["--tile", str(TILE), "--window", "256"], "--window: sizes --store windows"),
        (
            ["--store", str(STORE), "--tile-id", "15,47,-99", "--tile-gsd", "0.097"],
            "--tile-gsd: is for --tile images; a --store window's is its zoom's",
        ),
    ],
    ids=[
        "no-tile-id",
        "zoom",
        "not-mbtiles",
        "missing",
        "with-tile",
        "fdr-over-it",
        "window",
        "window-without-store",
        "gsd-over-the-zoom",
    ],
)
def test_what_a_store_cannot_serve_is_one_line_and_exit_2(engine_dir, tmp_path, args, needle):
    before = STORE.read_bytes()
    proc = _match(tmp_path, engine_dir, *args)
    assert proc.returncode == 2, proc.stderr[-2000:]
    said = [line for line in proc.stderr.splitlines() if not line.startswith("{")]
    assert needle in said[-1], said
    assert proc.stdout == "" and STORE.read_bytes() == before


def test_stored_map_features_serve_the_store_windows_as_extraction_would(engine_dir, tmp_path):
    """With the flight's windows built (``features build --flight-candidates``), ``match
    --store`` reads each window's features from the sidecar, and the match is the one that
    extracting them gives, bit for bit."""
    import shutil

    flight = shutil.copytree(FLIGHT, tmp_path / "flight")
    built = run_cli(
        *("features", "build", flight, "--strategy", "xfeat", "--workers", "0"),
        "--flight-candidates",
        cwd=tmp_path,
        engine_dir=engine_dir,
    )
    assert built.returncode == 0, built.stderr[-2000:]
    roll, pitch, yaw = FRAME["attitude_deg"]
    args = (
        *("--strategy", "xfeat", "--calibration", str(FLIGHT / "calibration.json")),
        *("--attitude", f"{roll},{pitch},{yaw}", "--height", str(FRAME["height_m"])),
        *("--store", str(flight / "tiles.mbtiles"), "--window", "448"),
        *(a for c in FRAME["candidates"] for a in ("--tile-id", _tile_id(c))),
    )
    outs, sources = [], []
    for stored in ("true", "false"):
        fdr = tmp_path / f"fdr_{stored}.jsonl"
        settings = {"C3_MATCHER_FDR__PATH": str(fdr), "C3_MATCHER_MATCHER__STORED_FEATURES": stored}
        query = ["match", "--query", str(FLIGHT / FRAME["image"]), *args]
        proc = run_cli(*query, cwd=tmp_path, engine_dir=engine_dir, settings=settings)
        assert proc.returncode == 0, proc.stderr[-2000:]
        out = json.loads(proc.stdout)
        out.pop("matched_at"), out.pop("timings_ms", None)
        outs.append(out)
        records = [json.loads(x) for x in fdr.read_text().splitlines()]
        (done,) = (r["payload"] for r in records if r["kind"] == "matcher.frame_done")
        sources.append(done["candidate_features"])
    assert sources == [["stored"] * 3, ["extracted"] * 3]
    assert outs[0] == outs[1] and outs[0]["per_candidate"][0]["inlier_count"] >= 80
