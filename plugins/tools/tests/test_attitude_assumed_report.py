"""A recorded flight whose log has no attitude is imported level (each frame marked
``attitude_assumed``): its telemetry look point is where a level camera would look, hundreds of
metres from where a tilted one does. ``replay`` and ``eval`` printed the estimate's distance
from that point as the matcher's error beside the GNSS accuracy (a 150-260 m miss beside
1.5 m) and counted it under good GNSS, saying nothing of the assumption. The figures now count
only frames whose attitude was measured; the assumed frames are listed, their own figure kept
apart and named as the level camera's. A PX4 ULog without attitude is written over frames of
the shipped demo flight, imported and flown with xfeat."""

from __future__ import annotations

import json
import shutil
import statistics
from dataclasses import replace
from pathlib import Path

import pytest

from c3_matcher.georef import haversine_m
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run import summarize
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog
from c3_matcher_tools.testing.outcomes import frame_outcome

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
CAL, STORE = str(DEMO / "calibration.json"), str(DEMO / "tiles.mbtiles")
FRAMES = range(4)


def _import(root: Path, name: str, flaws: tuple[str, ...]) -> Path:
    """The demo frames ``FRAMES`` imported from a ULog written with ``flaws``."""
    poses = fl.flight_poses(DEMO, FRAMES)
    images = root / f"images_{name}"
    images.mkdir()
    for i, p in enumerate(poses):
        shutil.copyfile(p.image, images / f"IMG_{i:04d}.jpg")
    log = write_ulog(root / f"{name}.ulg", poses, flaws=flaws)
    flight = root / name
    proc = run_cli("dataset", "import", images, log, CAL, STORE, flight, cwd=root)
    assert proc.returncode == 0, proc.stderr
    return flight


@pytest.fixture(scope="module")
def flights(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(the flight imported without attitude, the same flight with its attitude)."""
    root = tmp_path_factory.mktemp("attitude")
    return _import(root, "level", ("no_attitude",)), _import(root, "measured", ())


def _lines(path: Path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines()]


def test_replay_keeps_frames_of_an_assumed_attitude_out_of_its_figures(
    flights: tuple[Path, Path], engine_dir: Path, tmp_path: Path
) -> None:
    level, measured = flights
    out = tmp_path / "replay"
    proc = run_cli(
        "replay", level, "--strategy", "xfeat", "--out", out, cwd=tmp_path, engine_dir=engine_dir
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    results = _lines(out / "results.jsonl")
    assert [r["attitude_assumed"] for r in results] == [True] * len(FRAMES)
    located = [r for r in results if r["telemetry_error_m"] is not None]
    assert located, [r["status"] for r in results]
    # the fixes are right: near where the camera truly looked (the import with its attitude)
    truth = {f.index: f.telemetry for f in load_dataset(measured).frames}
    for r in located:
        t = truth[r["index"]]
        assert _metres((r["est_lat"], r["est_lon"]), (t["look_lat"], t["look_lon"])) < 8.0
    level_p50 = statistics.median(r["telemetry_error_m"] for r in located)
    assert level_p50 > 50.0  # the level camera's look point is far from the tilted one's
    report = json.loads((out / "report.json").read_text())
    assert report["telemetry_error_m_p50"] is None and report["telemetry_error_m_p95"] is None
    assert report["telemetry_error_m_p50_gnss_good"] is None
    assert report["telemetry_error_frames"] == 0
    assert report["attitude_assumed_frames"] == list(FRAMES)
    assert report["telemetry_error_m_p50_attitude_assumed"] == pytest.approx(level_p50)
    said = proc.stdout
    assert "estimate - telemetry look point m p50 n/a, p95 n/a over 0 located frame(s)" in said
    assert (
        f"attitude assumed level on {len(FRAMES)} frame(s) (0-{len(FRAMES) - 1}; the log has no "
        "attitude at their time): not counted above; estimate - a level camera's look point "
        f"m p50 {report['telemetry_error_m_p50_attitude_assumed']:.0f}"
    ) in said, said
    html = (out / "report.html").read_text()
    assert "attitude assumed level" in html and "a level camera&#x27;s look point" in html


def test_eval_says_the_attitude_was_assumed_and_records_it_per_frame(
    flights: tuple[Path, Path], engine_dir: Path, tmp_path: Path
) -> None:
    level, _ = flights
    out = tmp_path / "eval"
    proc = run_cli(
        "eval", level, "--strategy", "xfeat", "--no-baseline", "--determinism-frames", "1",
        "--samples", "0", "--out", out, cwd=tmp_path, engine_dir=engine_dir,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "xfeat: estimate - telemetry look point m p50 n/a" in proc.stdout
    assert "xfeat: attitude assumed level on 4 frame(s)" in proc.stdout
    [entry] = json.loads((out / "eval.json").read_text())["strategies"]
    assert [f["attitude_assumed"] for f in entry["per_frame"]] == [True] * len(FRAMES)
    assert entry["timing"]["telemetry_error_m_p50"] is None
    assert entry["timing"]["attitude_assumed_frames"] == list(FRAMES)
    assert entry["timing"]["telemetry_error_m_p50_attitude_assumed"] > 50.0


def _metres(a: tuple[float, float], b: tuple[float, float]) -> float:
    return float(haversine_m([[a[1], a[0]]], [[b[1], b[0]]])[0])


def test_the_summary_counts_measured_attitudes_and_keeps_assumed_ones_apart() -> None:
    near = dict(telemetry_lat=47.0, telemetry_lon=-99.0, gnss_accuracy_m=1.5)
    measured = [
        replace(frame_outcome(i), **near, telemetry_error_m=e, gnss_degraded=i == 3)
        for i, e in enumerate((1.0, 2.0, 3.0, 40.0))
    ]
    assumed = [
        replace(frame_outcome(i), **near, telemetry_error_m=e, gnss_degraded=False)
        for i, e in ((4, 150.0), (5, 250.0), (6, 200.0))
    ]
    assumed = [replace(o, attitude_assumed=True) for o in assumed]
    s = summarize([*measured, *assumed])
    assert s.with_telemetry == 7 and s.telemetry_error_frames == 4
    assert (s.telemetry_error_m_p50, s.telemetry_error_m_p50_gnss_good) == (2.5, 2.0)
    assert s.telemetry_error_m_p95 == pytest.approx(34.45)
    assert s.attitude_assumed_frames == (4, 5, 6)
    assert s.telemetry_error_m_p50_attitude_assumed == 200.0
    j = s.to_json()
    assert j["attitude_assumed_frames"] == [4, 5, 6] and json.loads(json.dumps(j)) == j
    only_assumed = summarize(assumed)
    assert only_assumed.telemetry_error_m_p50 is None
    assert only_assumed.telemetry_error_m_p95 is None
    assert only_assumed.telemetry_error_m_p50_gnss_good is None
    assert only_assumed.telemetry_error_m_p50_attitude_assumed == 200.0
    none_assumed = summarize(measured)
    assert none_assumed.attitude_assumed_frames == ()
    assert none_assumed.telemetry_error_m_p50_attitude_assumed is None
    assert none_assumed.telemetry_error_m_p50 == 2.5
