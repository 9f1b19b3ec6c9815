"""A flight over the antimeridian (Fiji, the Aleutians, Chukotka) is imported as it is anywhere
else, and ``match`` against windows of its store gives WGS84 longitudes.

The store is the shipped demo store moved west by whole tiles, so that its tiles straddle 180 deg:
the same pixels at the same web-mercator offsets, column 7359 now column 0. The demo flight moved
with it must get the candidates it gets at home, moved the same way; a vehicle looking across the
line is imported; the tile a metre across the line is a candidate; a fix is the one made at home,
moved, whichever side of the line its window is named on."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.tilestore.base import tile_centre_id
from c3_matcher.tilestore.geo import TILE_PX, lonlat_to_world_px
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.importer import ImportSpec, import_csv_flight
from c3_matcher_tools.dataset.proposals import propose_from_store
from c3_matcher_tools.dataset.sources.options import ProposalOptions
from c3_matcher_tools.dataset.telemetry import TelemetryRow
from c3_matcher_tools.testing.cli import run_cli

from .test_import_scale import CALIBRATION, DEMO, STORE, ZOOM, _flight

N = 1 << ZOOM
SHIFT = 7359  # the demo store's column 7359 becomes column 0
SHIFT_DEG = SHIFT * 360 / N
LAT = 47.0203620  # the middle of the store's rows


def _wrap(lon: float) -> float:
    return (lon + 180.0) % 360.0 - 180.0


def _moved(lon: float) -> float:
    return _wrap(lon - SHIFT_DEG)


@pytest.fixture(scope="module")
def across(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The demo store, its tiles in columns 32764..32767 and 0..2 (both sides of 180 deg)."""
    store = tmp_path_factory.mktemp("across") / "tiles.mbtiles"
    shutil.copyfile(STORE, store)
    db = sqlite3.connect(store)
    with db:
        for table in ("tiles", "c3_tile_digest"):
            db.execute(f"UPDATE {table} SET tile_column = (tile_column - ? + ?) % ?", (SHIFT, N, N))
    db.close()
    return store


def _moved_flight(root: Path, store: Path) -> ImportSpec:
    """The first 30 demo frames, their longitudes moved with the store."""
    spec = _flight(root, store, frames=30)
    lines = spec.telemetry_csv.read_text().splitlines()
    rows = [line.split(",") for line in lines[1:]]
    moved = [",".join([*r[:3], repr(_moved(float(r[3]))), *r[4:]]) for r in rows]
    spec.telemetry_csv.write_text("\n".join([lines[0], *moved]) + "\n")
    return spec


def test_a_flight_over_the_line_gets_the_candidates_it_gets_at_home(
    tmp_path: Path, across: Path
) -> None:
    import_csv_flight(_flight(tmp_path / "home", STORE, frames=30), tmp_path / "a", name="f")
    import_csv_flight(_moved_flight(tmp_path / "line", across), tmp_path / "b", name="f")
    home, line = load_dataset(tmp_path / "a").frames, load_dataset(tmp_path / "b").frames
    sides = {f.telemetry["look_lon"] > 0 for f in line}
    assert sides == {True, False}  # looks on both sides of the line
    for h, m in zip(home, line, strict=True):
        assert -180 <= m.telemetry["look_lon"] < 180
        assert m.telemetry["look_lon"] == pytest.approx(_moved(h.telemetry["look_lon"]), abs=1e-9)
        assert [c.tile_id.lat for c in m.candidates] == [c.tile_id.lat for c in h.candidates]
        moved = [_moved(c.tile_id.lon) for c in h.candidates]
        assert [c.tile_id.lon for c in m.candidates] == pytest.approx(moved, abs=1e-9)


def test_a_vehicle_looking_across_the_line_is_imported(tmp_path: Path, across: Path) -> None:
    """11 m west of 180 deg, looking 180 m east (pitch 20 deg, yaw 90 deg, 500 m up)."""
    spec = _flight(tmp_path, across, frames=2)
    lines = spec.telemetry_csv.read_text().splitlines()
    names = [line.split(",")[1] for line in lines[1:]]
    spec.telemetry_csv.write_text(
        f"{lines[0]}\n0.0,{names[0]},{LAT},179.99985,500,0,20,90\n"
        f"1.0,{names[1]},{LAT},-179.999,500,0,0,90\n"
    )
    r = run_cli(
        *("dataset", "import", spec.images_dir, spec.telemetry_csv, DEMO / "calibration.json"),
        *(across, "out", "--uncertainty-m", "300", "--candidates", "3"),
        cwd=tmp_path,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    looks = [f.telemetry["look_lon"] for f in load_dataset(tmp_path / "out").frames]
    assert -179.999 < looks[0] < -179.997 and looks[1] == -179.999  # 182 m east of 179.99985


@pytest.mark.parametrize("lon", [179.99999, -179.99999])
def test_the_tile_a_metre_across_the_line_is_a_candidate(across: Path, lon: float) -> None:
    row = TelemetryRow(2, 0.0, "x.jpg", LAT, lon, 500.0, 0.0, 0.0, 0.0)
    options = ProposalOptions(across, uncertainty_m=300.0, candidates=3)
    ((_, cands),) = propose_from_store([row], CALIBRATION, options).looks
    assert cands is not None
    ty = int(lonlat_to_world_px([[0.0, LAT]], ZOOM)[0][1] // TILE_PX)
    other = tile_centre_id(ZOOM, 0 if lon > 0 else N - 1, ty)
    (distance,) = [m for t, m in cands if t == other]
    assert distance == pytest.approx(0.76, abs=0.05)  # 1e-5 deg of longitude at 47 N


def _fix(tmp_path: Path, store: Path, window_lon: float, window_lat: float) -> dict[str, Any]:
    """``match`` of demo frame 0 against the ``store`` window centred at the given point."""
    f = json.loads((DEMO / "frames.jsonl").read_text().splitlines()[0])
    r = run_cli(
        *("match", "--query", DEMO / f["image"], "--calibration", DEMO / "calibration.json"),
        *("--attitude", ",".join(map(str, f["attitude_deg"])), "--height", f["height_m"]),
        *("--store", store, "--tile-id", f"{ZOOM},{window_lat!r},{window_lon!r}"),
        *("--strategy", "sift_magsac", "--no-correspondences"),
        cwd=tmp_path,
        settings={"C3_MATCHER_FDR__PATH": str(tmp_path / "fdr.jsonl")},
    )
    assert r.returncode == 0, r.stderr[-2000:]
    return dict(json.loads(r.stdout))


def test_a_fix_across_the_line_from_its_window_is_a_wgs84_longitude(
    tmp_path: Path, across: Path
) -> None:
    """Frame 0's window is centred on the line (column 0's west edge: -180 or 180 deg), the
    fix some 40 m west of it. The centre is the fix made at home, moved; the footprint is the one
    made at home, moved, one ring around it (continuous: it crosses the line, so its points
    east of the line lie beyond 180 deg)."""
    frame = json.loads((DEMO / "frames.jsonl").read_text().splitlines()[0])
    _, lat, lon = next(c["tile_id"] for c in frame["candidates"] if c["is_true"])
    assert _moved(lon) == -180.0
    home = _fix(tmp_path, STORE, lon, lat)
    for window in (-180.0, 180.0):
        fix = _fix(tmp_path, across, window, lat)
        assert fix["centre_lat"] == home["centre_lat"]
        assert -180 <= fix["centre_lon"] < 180
        assert fix["centre_lon"] == pytest.approx(_moved(home["centre_lon"]), abs=1e-9)
        offsets = [p[0] - fix["centre_lon"] for p in fix["footprint"]]
        at_home = [p[0] - home["centre_lon"] for p in home["footprint"]]
        assert offsets == pytest.approx(at_home, abs=1e-9)
