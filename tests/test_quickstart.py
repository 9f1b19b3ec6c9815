"""The README's quick start, followed as a new user would: after the demo (engines built where
``scripts/demo`` builds them), the installed ``c3-matcher`` is run from the user's own directory
with no ``C3_MATCHER_*`` variable and a fresh home: ``match`` on the user's own files, ``tiles
build`` from a GeoTIFF, ``dataset import`` of a recorded flight, ``replay``.

Engines: the conftest ``engine_dir`` fixture builds them where ``c3-matcher`` looks by default
(this checkout's ``.engines``). Only when the test run itself was pointed at another engine
directory (``C3_MATCHER_ENGINES__DIRECTORY``, as a user would do it too) is that directory
passed on.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from c3_matcher.engines.store import default_engine_dir
from c3_matcher.georef import haversine_m
from c3_matcher_tools.dataset.format import load_dataset

REPO = Path(__file__).resolve().parents[1]
EXE = Path(sys.executable).with_name("c3-matcher")  # the installed command, .venv/bin/c3-matcher
DEMO = REPO / "data" / "demo"
FLIGHT = REPO / "data" / "flights" / "naip_demo"
GEOTIFF = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"


@pytest.fixture
def user(engine_dir: Path, tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A new user's working directory and environment (fresh home, no c3-matcher settings)."""
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("C3_MATCHER_", "XDG_")) and k != "VIRTUAL_ENV"
    }
    env["HOME"] = str(tmp_path / "home")
    if engine_dir.resolve() != default_engine_dir().resolve():
        env["C3_MATCHER_ENGINES__DIRECTORY"] = str(engine_dir)
    work = tmp_path / "my-flight"
    work.mkdir()
    return work, env


def _c3(user: tuple[Path, dict[str, str]], *args: str) -> subprocess.CompletedProcess[str]:
    work, env = user
    return subprocess.run(
        [str(EXE), *args], cwd=work, env=env, capture_output=True, text=True, timeout=900
    )


@pytest.mark.slow
def test_quick_start_as_a_new_user(user: tuple[Path, dict[str, str]]) -> None:
    work, env = user

    # 2. the command on the path: it finds the engines the demo built, from this directory
    listed = _c3(user, "engines", "verify", "--json")
    assert listed.returncode == 0, listed.stdout + listed.stderr[-2000:]
    assert all(e["ok"] for e in json.loads(listed.stdout)["engines"])

    # 3. your own frame: the user's files, in the user's directory, the README's command
    for name in ("frame.jpg", "tile_a.png", "tile_b.png", "tile_c.png", "calibration.json"):
        shutil.copy(DEMO / name, work / name)
    meta = json.loads((DEMO / "demo.json").read_text())
    att = meta["attitude_deg"]
    proc = _c3(
        user,
        "match",
        "--query",
        "frame.jpg",
        *("--tile", "tile_a.png", "--tile", "tile_b.png", "--tile", "tile_c.png"),
        *("--tile-gsd", str(meta["tile_gsd_m"]), "--calibration", "calibration.json"),
        *("--attitude", f"{att['roll']},{att['pitch']},{att['yaw']}"),
        *("--height", str(meta["height_m"]), "--viz", "match.png", "--max-keypoints", "1024"),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout)
    true_index = next(i for i, t in enumerate(meta["tiles"]) if t["true"])
    assert result["per_candidate"][0]["tile_index"] == true_index
    assert result["per_candidate"][0]["inlier_count"] >= 60
    assert result["per_candidate"][0]["tile_id"] is None  # no --tile-id: no place made up
    assert (work / "match.png").stat().st_size > 0
    fdr = Path(env["HOME"]) / ".local" / "share" / "c3-matcher" / "fdr" / "c3_fdr.jsonl"
    assert fdr.is_file()  # the default recorder, in the user's data directory ...
    stated = [json.loads(x) for x in proc.stderr.splitlines() if x.startswith("{")]
    assert any(r["kind"] == "c3.fdr.default_path" and r["path"] == str(fdr) for r in stated)

    # 4. your own map: a tile store from a GeoTIFF
    proc = _c3(user, "tiles", "build", str(GEOTIFF), "tiles.mbtiles", "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads(proc.stdout)["tiles"] > 0
    info = _c3(user, "tiles", "info", "tiles.mbtiles", "--json")
    assert info.returncode == 0 and json.loads(info.stdout)["tiles"], info.stderr

    # 5. your own flight: images + telemetry CSV (the README's columns) -> dataset -> replay
    images = work / "images"
    images.mkdir()
    rows = ["time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg"]
    records = [json.loads(x) for x in (FLIGHT / "frames.jsonl").read_text().splitlines()][:3]
    for f in records:
        name = f"IMG_{f['index']:04d}.jpg"
        shutil.copy(FLIGHT / f["image"], images / name)
        r, p, y = f["attitude_deg"]
        lat, lon = f["pose"]["nadir_lat"], f["pose"]["nadir_lon"]
        rows.append(f"{f['captured_at_ns'] / 1e9},{name},{lat},{lon},{f['height_m']},{r},{p},{y}")
    (work / "telemetry.csv").write_text("\n".join(rows) + "\n")
    shutil.copy(FLIGHT / "calibration.json", work / "camera.json")
    proc = _c3(
        user,
        *("dataset", "import", "images", "telemetry.csv", "camera.json", "tiles.mbtiles"),
        *("myflight", "--uncertainty-m", "50", "--candidates", "3"),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    proc = _c3(user, "replay", "myflight", "--strategy", "xfeat", "--out", "myflight-replay")
    assert proc.returncode == 0, proc.stderr[-3000:]
    replay = work / "myflight-replay"
    results = [json.loads(x) for x in (replay / "results.jsonl").read_text().splitlines()]
    assert len(results) == len(records)
    ok = [r for r in results if r["status"] == "ok"]
    assert len(ok) >= 2, [r["status"] for r in results]
    frames = {f.index: f for f in load_dataset(work / "myflight").frames}
    for r in ok:  # located where the (here: true) telemetry says the camera looks
        t = frames[r["index"]].telemetry
        look = (t["look_lon"], t["look_lat"])
        assert float(haversine_m((r["est_lon"], r["est_lat"]), look)[0]) < 30.0
    assert (replay / "report.html").is_file() and (replay / "flight.geojson").is_file()
