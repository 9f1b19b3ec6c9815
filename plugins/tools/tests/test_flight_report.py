"""What a user sees after ``c3-matcher replay`` on the shipped demo flight (real engines, the
xfeat strategy for speed): georeferenced results (best homography, centre lat/lon, footprint)
with position errors in metres, GeoJSON of truth and estimate, a self-contained report.html that
real headless Chromium renders with no console errors and non-blank plots, and a flight without
ground truth replayed without scoring."""

from __future__ import annotations

import base64
import json
import math
import re
import shutil
import statistics
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
CHROMIUM = Path("/usr/bin/chromium")
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--no-first-run",
    "--disable-component-update",
    "--disable-sync",
]


def c3(args: list[str], engine_dir: Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, cwd=REPO, engine_dir=engine_dir, timeout=1200)


@pytest.fixture(scope="module")
def replayed(engine_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """8 frames of the demo flight through xfeat (about 1.5 s a frame on 2 shared cores)."""
    out = tmp_path_factory.mktemp("replay")
    proc = c3(
        ["replay", str(DEMO), "--strategy", "xfeat", "--limit", "8", "--out", str(out), "--json"],
        engine_dir,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


@pytest.fixture(scope="session")
def chromium() -> Path:
    if not CHROMIUM.exists():
        subprocess.run(["apt-get", "install", "-y", "chromium"], check=False, timeout=900)
    if not CHROMIUM.exists():
        pytest.fail("headless Chromium is required: apt-get install -y chromium failed")
    return CHROMIUM


def test_results_are_georeferenced_with_errors_in_metres(replayed: Path) -> None:
    report = json.loads((replayed / "report.json").read_text())
    assert report["strategy"] == "xfeat" and report["settings"]["strategy"] == "xfeat"
    assert report["matcher_labels"] and all("xfeat" in x for x in report["matcher_labels"])
    rows = [json.loads(line) for line in (replayed / "results.jsonl").read_text().splitlines()]
    ok = [r for r in rows if r["status"] == "ok"]
    assert len(ok) >= 6
    for r in ok:
        res = r["result"]
        assert np.asarray(res["best_homography"]).shape == (3, 3)
        ring = np.asarray(res["footprint"])
        assert ring.shape[1] == 2 and np.allclose(ring[0], ring[-1])
        assert _twice_area(ring) > 0  # a GeoJSON exterior ring: counterclockwise
        assert abs(res["centre_lat"] - 47.0) < 0.1 and abs(res["centre_lon"] + 99.15) < 0.1
        assert r["truth_lat"] is not None and r["position_error_m"] is not None
    correct = [r for r in ok if r["correct"]]
    # the demo frames are 2.6 m/px: a correct match puts the centre within a few metres
    assert max(r["position_error_m"] for r in correct) < 10.0
    assert report["position_error_m_p50"] < 5.0
    # each error is the distance between the row's own estimate and truth, in metres
    distances = []
    for r in ok:
        est = (r["est_lat"], r["est_lon"])
        assert est == (r["result"]["centre_lat"], r["result"]["centre_lon"])
        distances.append(_great_circle_m(*est, r["truth_lat"], r["truth_lon"]))
        assert r["position_error_m"] == pytest.approx(distances[-1], abs=1e-6), r["index"]
    assert max(distances) > 0.1  # metres to compare, not all 0
    assert report["position_error_m_p50"] == pytest.approx(statistics.median(distances), abs=1e-6)


def test_geojson_holds_truth_and_estimate(replayed: Path) -> None:
    gj = json.loads((replayed / "flight.geojson").read_text())
    assert gj["type"] == "FeatureCollection"
    kinds = {f["properties"]["kind"] for f in gj["features"]}
    assert {"truth_track", "estimate_track", "truth", "estimate", "footprint", "error"} <= kinds
    for f in gj["features"]:
        coords = np.asarray(
            f["geometry"]["coordinates"][0]
            if f["geometry"]["type"] == "Polygon"
            else f["geometry"]["coordinates"]
        ).reshape(-1, 2)
        assert np.all(np.abs(coords[:, 0] + 99.15) < 0.1)  # lon first (RFC 7946)
        assert np.all(np.abs(coords[:, 1] - 47.0) < 0.1)
        if f["geometry"]["type"] == "Polygon":  # an exterior ring: closed, counterclockwise
            assert (coords[0] == coords[-1]).all()
            assert _twice_area(coords) > 0
    rows = [json.loads(line) for line in (replayed / "results.jsonl").read_text().splitlines()]
    rings = {r["index"]: r["result"]["footprint"] for r in rows if r["status"] == "ok"}
    polygons = [f for f in gj["features"] if f["properties"]["kind"] == "footprint"]
    assert len(polygons) == len(rings)
    for f in polygons:  # the result's ring as it is: every output winds it the same way
        assert f["geometry"]["coordinates"] == [rings[f["properties"]["frame"]]]


def _great_circle_m(lat_a: float, lon_a: float, lat_b: float, lon_b: float) -> float:
    """Metres along the sphere of the mean Earth radius (IUGG, 6371008.8 m) between two
    points (deg), by the haversine formula."""
    pa, pb = math.radians(lat_a), math.radians(lat_b)
    dp, dl = pb - pa, math.radians(lon_b - lon_a)
    h = math.sin(dp / 2) ** 2 + math.cos(pa) * math.cos(pb) * math.sin(dl / 2) ** 2
    return 2 * 6_371_008.8 * math.asin(math.sqrt(h))


def _twice_area(ring: np.ndarray) -> float:
    """Twice the signed shoelace area of a closed lon/lat ring (> 0: counterclockwise)."""
    x, y = ring[:, 0], ring[:, 1]
    return float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))


def _data_images(html: str) -> list[np.ndarray]:
    out = []
    for m in re.finditer(r'src="data:image/(png|jpeg);base64,([^"]+)"', html):
        buf = np.frombuffer(base64.b64decode(m.group(2)), np.uint8)
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        assert img is not None, "an embedded image does not decode"
        out.append(img)
    return out


def test_report_html_is_self_contained(replayed: Path) -> None:
    html = (replayed / "report.html").read_text()
    assert "<script" not in html and "http://" not in html and "https://" not in html
    images = _data_images(html)
    assert len(images) >= 4  # trajectory, per-frame plots, gallery
    for img in images:
        assert img.shape[0] > 100 and img.shape[1] > 100
        assert float(img.std()) > 10.0, "a blank (uniform) plot"
    assert 'id="trajectory"' in html and 'id="per-frame"' in html
    assert "strategy replayed" in html and "xfeat" in html
    assert "best: frame" in html  # every frame right: none is among the worst


def test_report_renders_in_headless_chromium(
    replayed: Path, chromium: Path, tmp_path: Path
) -> None:
    page = (replayed / "report.html").resolve().as_uri()
    profile = tmp_path / "profile"
    shot = tmp_path / "shot.png"
    proc = subprocess.run(
        [
            str(chromium),
            *FLAGS,
            f"--user-data-dir={profile}",
            "--enable-logging=stderr",
            "--v=0",
            "--window-size=1280,2000",
            f"--screenshot={shot}",
            page,
        ],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    console = [line for line in proc.stderr.splitlines() if "CONSOLE" in line]
    assert not console, console
    img = cv2.imread(str(shot))
    assert img is not None and img.shape[0] >= 1000
    # the plots rendered: the page is not a blank white sheet
    assert float(img.std()) > 20.0
    dom = subprocess.run(
        [str(chromium), *FLAGS, f"--user-data-dir={tmp_path / 'p2'}", "--dump-dom", page],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert dom.returncode == 0 and 'id="trajectory"' in dom.stdout


def test_flight_without_ground_truth_replays(engine_dir: Path, tmp_path: Path) -> None:
    flight = tmp_path / "recorded"
    flight.mkdir()
    for name in ("dataset.json", "calibration.json", "tiles.mbtiles"):
        shutil.copyfile(DEMO / name, flight / name)
    (flight / "frames").mkdir()
    lines = []
    for line in (DEMO / "frames.jsonl").read_text().splitlines()[:3]:
        rec = json.loads(line)
        shutil.copyfile(DEMO / rec["image"], flight / rec["image"])
        rec.pop("true_tile_present")
        rec["pose"] = {}
        rec["candidates"] = [
            {"tile_id": c["tile_id"], "score": c["score"]} for c in rec["candidates"]
        ]
        lines.append(json.dumps(rec))
    (flight / "frames.jsonl").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    proc = c3(
        ["replay", str(flight), "--strategy", "xfeat", "--out", str(out), "--json"], engine_dir
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout)
    assert report["frames"] == 3 and report["with_truth"] == 0 and report["ok"] >= 2
    rows = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
    assert all(r["has_truth"] is False and r["position_error_m"] is None for r in rows)
    assert any(r["est_lat"] is not None for r in rows)
    assert (out / "report.html").is_file() and (out / "flight.geojson").is_file()
