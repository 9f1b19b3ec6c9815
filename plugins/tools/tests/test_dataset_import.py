"""``c3-matcher dataset import``: a recorded flight (images, telemetry CSV, calibration) becomes a
``c3-flight/1`` dataset without ground truth; inputs are checked before anything is written.
The flight is the shipped demo's frames with their telemetry written out from frames.jsonl
(nadir position, attitude, height), replayed through xfeat: the located frames lie within a few
metres of where the telemetry says the camera looks."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.georef import haversine_m
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.importer import ImportSpec, import_csv_flight
from c3_matcher_tools.dataset.sources.options import ProposalOptions
from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
HEADER = "time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg"


def _recorded(root: Path, frames: range = range(6)) -> tuple[Path, Path]:
    """IMG_*.jpg and telemetry.csv of demo frames (truth-free inputs a user would have)."""
    images = root / "images"
    images.mkdir()
    records = [json.loads(x) for x in (DEMO / "frames.jsonl").read_text().splitlines()]
    rows = [HEADER]
    for i in frames:
        f = records[i]
        name = f"IMG_{i:04d}.jpg"
        shutil.copyfile(DEMO / f["image"], images / name)
        p = f["pose"]
        r, pi, y = f["attitude_deg"]
        t = f["captured_at_ns"] / 1e9
        lat, lon = p["nadir_lat"], p["nadir_lon"]
        rows.append(f"{t},{name},{lat},{lon},{f['height_m']},{r},{pi},{y}")
    csv = root / "telemetry.csv"
    csv.write_text("\n".join(rows) + "\n")
    return images, csv


def _spec(images: Path, csv: Path, **kw: object) -> ImportSpec:
    proposal = ProposalOptions(DEMO / "tiles.mbtiles", **kw)  # type: ignore[arg-type]
    return ImportSpec(images, csv, DEMO / "calibration.json", proposal)


def test_import_builds_truth_free_dataset(tmp_path: Path) -> None:
    images, csv = _recorded(tmp_path)
    out = tmp_path / "flight"
    summary = import_csv_flight(_spec(images, csv, candidates=4, uncertainty_m=80.0), out)
    assert summary.frames == 6 and summary.zoom == 15
    d = load_dataset(out)
    assert d.meta["format"] == "c3-flight/1" and d.candidate_size_px == 512
    assert not any(f.has_truth for f in d.frames)
    with d.open_store() as store:
        for f in d.frames:
            assert len(f.candidates) == 4
            assert len({c.tile_id for c in f.candidates}) == 4
            assert [c.score for c in f.candidates] == [0.9, 0.8, 0.7, 0.6]
            assert f.telemetry["uncertainty_m"] == 80.0
            rerank = d.rerank(f, store)
            assert rerank.candidates[0].tile_pixels_handle.decode().shape == (512, 512, 3)
    # deterministic: the same inputs give the same candidates and frame ids
    again = import_csv_flight(
        _spec(images, csv, candidates=4, uncertainty_m=80.0), tmp_path / "b", name="flight"
    )
    assert again.frames == 6
    assert (out / "frames.jsonl").read_text() == (tmp_path / "b" / "frames.jsonl").read_text()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp dir left


@pytest.mark.parametrize(
    ("mutate", "needle"),
    [
        (
            lambda csv, images: csv.write_text(csv.read_text().replace("yaw_deg", "heading")),
            "yaw_deg",
        ),
        (
            lambda csv, images: (images / "IMG_0001.jpg").write_bytes(
                (DEMO / "tiles.mbtiles").read_bytes()[:100]
            ),
            "not a readable image",
        ),
        (
            lambda csv, images: csv.write_text(csv.read_text().replace(",780.0,", ",-5,", 1)),
            "altitude_m",
        ),
        (
            lambda csv, images: csv.write_text(csv.read_text().replace("47.0", "12.0", 1)),
            "outside the store's coverage",
        ),
        (
            lambda csv, images: csv.write_text(csv.read_text() + "0.0,IMG_0000.jpg,1,1,1,0,0,0\n"),
            "already on line",
        ),
    ],
)
def test_import_checks_inputs_before_writing(tmp_path: Path, mutate, needle: str) -> None:  # type: ignore[no-untyped-def]
    images, csv = _recorded(tmp_path, range(3))
    mutate(csv, images)
    out = tmp_path / "flight"
    with pytest.raises(InvalidInputError, match=needle):
        import_csv_flight(_spec(images, csv), out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["images", "telemetry.csv"]


def test_import_refuses_existing_out_and_bad_zoom(tmp_path: Path) -> None:
    images, csv = _recorded(tmp_path, range(2))
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "keep.txt").write_text("x")
    with pytest.raises(InvalidInputError, match="already exists"):
        import_csv_flight(_spec(images, csv), tmp_path / "taken")
    assert (tmp_path / "taken" / "keep.txt").read_text() == "x"
    with pytest.raises(InvalidInputError, match="--zoom"):
        import_csv_flight(_spec(images, csv, zoom=3), tmp_path / "z")
    assert not (tmp_path / "z").exists()


def test_import_then_replay_locates_frames_near_telemetry(engine_dir: Path, tmp_path: Path) -> None:
    images, csv = _recorded(tmp_path, range(6))

    def c3(*args: str) -> subprocess.CompletedProcess[str]:
        return run_cli(*args, cwd=REPO, engine_dir=engine_dir)

    flight = tmp_path / "flight"
    cal = str(DEMO / "calibration.json")
    proc = c3(
        "dataset",
        "import",
        str(images),
        str(csv),
        cal,
        str(DEMO / "tiles.mbtiles"),
        str(flight),
        "--json",
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads(proc.stdout)["frames"] == 6
    help_text = c3("dataset", "import", "--help").stdout
    for word in ("time_s", "altitude_m", "WGS84", "ABOVE GROUND", "TRUE north", "Z-Y-X"):
        assert word in help_text
    out = tmp_path / "replay"
    proc = c3("replay", str(flight), "--strategy", "xfeat", "--out", str(out), "--json")
    assert proc.returncode == 0, proc.stderr[-3000:]
    frames = {f.index: f for f in load_dataset(flight).frames}
    results = [json.loads(x) for x in (out / "results.jsonl").read_text().splitlines()]
    ok = [r for r in results if r["status"] == "ok"]
    assert len(ok) >= 4, [r["status"] for r in results]
    errors = []
    for r in ok:
        t = frames[r["index"]].telemetry
        assert r["position_error_m"] is None  # no ground truth: nothing scored
        errors.append(
            float(haversine_m((r["est_lon"], r["est_lat"]), (t["look_lon"], t["look_lat"]))[0])
        )
    print("estimate - telemetry look point, m:", [round(e, 1) for e in errors])
    assert max(errors) < 30.0, errors
    assert (out / "report.html").is_file() and (out / "flight.geojson").is_file()


def test_tiles_info_json_and_text() -> None:
    def run(*extra: str) -> str:
        proc = run_cli("tiles", "info", *extra, cwd=REPO, timeout=120)
        assert proc.returncode == 0, proc.stderr
        return proc.stdout

    info = json.loads(run(str(DEMO / "tiles.mbtiles"), "--json"))
    assert info["tiles"] == {"15": 35}
    assert "zoom 15: 35 tiles" in run(str(DEMO / "tiles.mbtiles"))
