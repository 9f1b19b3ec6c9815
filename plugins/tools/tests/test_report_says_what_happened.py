"""What replay says of a run is what happened: the wrong fixes eval counts false-confident are
counted in its summary (``report.json``), on stdout and on the flight report's headline, their
bars drawn in a warning colour, and each map feature says its verdict; a frame that raised with
its true tile absent (the right answer, C3-IT-05) is a right refusal, counted and marked apart
from the failures; the noise put on the attitudes is said; the per-frame chart always shows the
inlier threshold; the settings read in the product's words, ``[lightglue]``'s only where the
strategy ran LightGlue. Outcomes set per frame on the shipped demo flight, then real replays of
it (xfeat)."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
from pathlib import Path
from typing import Any

import pytest
from matplotlib.colors import to_rgba

from c3_matcher_tools.dataset.format import FlightDataset, load_dataset, with_attitude_noise
from c3_matcher_tools.evaluate import WRONG_FIX_PX, metrics
from c3_matcher_tools.geojson import flight_geojson
from c3_matcher_tools.replay import _report_lines
from c3_matcher_tools.report import charts as report_charts
from c3_matcher_tools.report import html as report_html
from c3_matcher_tools.report.charts import STATUS_COLOUR, WARNING
from c3_matcher_tools.report.trajectory import RIGHT_REFUSAL
from c3_matcher_tools.run import FrameOutcome, summarize, truth_position, write_html_report
from c3_matcher_tools.run.records import FrameStatus
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.outcomes import frame_outcome
from c3_matcher_tools.testing.report import drawn_report

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
WRONG_FIXES = (2, 5, 6)


def _placed(dataset: FlightDataset, o: FrameOutcome, error_m: float | None) -> FrameOutcome:
    """``o`` at where its frame truly looks, its estimate ``error_m`` north of it (None: no
    estimate, a frame that raised)."""
    truth = truth_position(dataset, dataset.frames[o.index])
    assert truth is not None
    lat, lon = truth
    o = dataclasses.replace(o, truth_lat=lat, truth_lon=lon)
    if error_m is None:
        return o
    moved = lat + error_m / 111_320.0
    return dataclasses.replace(o, est_lat=moved, est_lon=lon, position_error_m=error_m)


def _outcomes(dataset: FlightDataset) -> list[FrameOutcome]:
    """0: the true tile; 1: another tile, placed right; 2: another tile, placed wrong; 3:
    raised with its true tile there; 4: raised without it (rightly); 5: the true tile placed
    wrong; 6: a pick without its true tile, placed wrong; 7: a pick without ground truth."""
    raised = FrameStatus.INSUFFICIENT
    return [
        _placed(dataset, frame_outcome(0), 1.0),
        _placed(dataset, frame_outcome(1, correct=False, error_px=3.0), 2.0),
        _placed(dataset, frame_outcome(2, correct=False, error_px=300.0), 400.0),
        _placed(dataset, frame_outcome(3, status=raised), None),
        _placed(dataset, frame_outcome(4, status=raised, true_present=False), None),
        _placed(dataset, frame_outcome(5, error_px=40.0), 50.0),
        _placed(dataset, frame_outcome(6, correct=False, true_present=False, error_px=250.0), 300),
        dataclasses.replace(frame_outcome(7, has_truth=False), est_lat=47.0, est_lon=-99.15),
    ]


@pytest.fixture(scope="module")
def demo() -> FlightDataset:
    return load_dataset(DEMO)


@pytest.fixture(scope="module")
def drawn(demo: FlightDataset, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, list[Any]]:
    """(report.html text, its figures) of :func:`_outcomes`."""
    return drawn_report(tmp_path_factory.mktemp("report"), demo, _outcomes(demo))


def _kpis(text: str) -> dict[str, str]:
    return dict(re.findall(r"<div>([^<]*)<b>([^<]*)</b></div>", text))


def test_the_run_summary_counts_the_wrong_fixes_eval_counts(demo: FlightDataset) -> None:
    outcomes = _outcomes(demo)
    summary = summarize(outcomes)
    assert summary.false_confident_frames == metrics(outcomes, []).false_confident.frames
    assert summary.false_confident_frames == WRONG_FIXES and summary.scored == 7
    shown = summary.to_json()  # report.json's and eval.json's summary
    assert shown["false_confident"] == 3 and shown["false_confident_frames"] == list(WRONG_FIXES)


def _stdout(demo: FlightDataset, noise: dict[str, Any] | None) -> list[str]:
    """replay's table of :func:`_outcomes`, run with ``noise`` on its attitudes."""
    files = {k: f"/x/{k}" for k in ("results", "fdr", "geojson", "html", "log")}
    report = {"strategy": "xfeat", "wall_s": 1.0, "startup_s": 0.1, "attitude_noise": noise}
    return _report_lines("naip_demo", {**report, **files}, summarize(_outcomes(demo)), Path("x"))


def test_replay_prints_the_wrong_fixes_as_eval_counts_them(demo: FlightDataset) -> None:
    lines = _stdout(demo, None)
    said = [line for line in lines if line.strip().startswith("false-conf")]
    assert said == [
        f"  false-conf 3/7 frames: picks whose inliers miss ground truth by > {WRONG_FIX_PX:g} px "
        "(bar: zero); frames 2, 5-6"
    ]
    assert lines[0].endswith("(startup 0.1 s)")  # no noise: nothing said of it


def test_replay_says_the_noise_put_on_the_attitudes(demo: FlightDataset) -> None:
    first = _stdout(demo, {"sigma_deg": 2.0, "seed": 0})[0]
    assert first.endswith("(startup 0.1 s), attitude noise 2 deg (1 sigma)")


def test_the_headline_counts_wrong_fixes_and_right_refusals_apart(
    drawn: tuple[str, list[Any]],
) -> None:
    kpis = _kpis(drawn[0])
    assert kpis["matched"] == "6"
    assert kpis["wrong fixes (false-confident)"] == "3/7"
    assert kpis["failed (true tile present)"] == "1"  # frame 3
    assert kpis["rightly raised (true tile absent)"] == "1/2"  # frame 4 of 4 and 6
    assert "failed" not in kpis  # no card counts a right refusal as a failure


def test_a_flight_with_every_true_tile_there_has_one_failed_card(
    demo: FlightDataset, tmp_path: Path
) -> None:
    outcomes = [frame_outcome(0), frame_outcome(1, status=FrameStatus.INSUFFICIENT)]
    kpis = _kpis(drawn_report(tmp_path, demo, outcomes)[0])
    assert kpis["failed"] == "1" and not any(k.startswith("rightly") for k in kpis)


def test_the_frames_table_and_the_chart_mark_a_right_refusal(
    drawn: tuple[str, list[Any]],
) -> None:
    text, figures = drawn
    assert (
        "<td>4</td><td>insufficient</td><td>0</td><td>R rightly raised (true tile absent)" in text
    )
    inliers = figures[1].axes[0]
    marks = {round(t.get_position()[0]): t.get_text() for t in inliers.texts}
    assert marks[3] == "F" and marks[4] == "R"
    legend = [t.get_text() for t in inliers.get_legend().get_texts()]
    assert "R: rightly raised (true tile absent)" in legend


def test_wrong_fix_and_right_refusal_bars_have_their_colours(drawn: tuple[str, list[Any]]) -> None:
    bars = [p for p in drawn[1][1].axes[0].patches if p.get_width() == 0.8]  # not the bands
    colour = {round(b.get_x() + b.get_width() / 2): b.get_facecolor() for b in bars}
    for frame in WRONG_FIXES:
        assert colour[frame] == to_rgba(WARNING)
    assert colour[4] == to_rgba(RIGHT_REFUSAL)
    assert colour[3] == to_rgba(STATUS_COLOUR[FrameStatus.INSUFFICIENT])
    assert colour[0] == colour[1] == to_rgba(STATUS_COLOUR[FrameStatus.OK])


def test_the_map_marks_a_right_refusal_apart_from_a_failure(drawn: tuple[str, list[Any]]) -> None:
    trajectory = drawn[1][0].axes[0]
    marked = {c.get_label(): len(c.get_offsets()) for c in trajectory.collections}
    assert marked["failed frame (truth)"] == 1 and marked["rightly raised (true tile absent)"] == 1


def test_the_threshold_line_is_drawn_when_every_bar_is_below_it(
    demo: FlightDataset, tmp_path: Path
) -> None:
    outcomes = [frame_outcome(i, inliers=20) for i in range(3)]  # drawn against 60
    _, figures = drawn_report(tmp_path, demo, outcomes)
    inliers = figures[1].axes[0]
    threshold = [line for line in inliers.get_lines() if line.get_linestyle() == "--"]
    assert threshold and threshold[0].get_ydata()[0] == 60
    assert inliers.get_ylim()[1] > 60


def test_each_map_feature_says_its_verdict(demo: FlightDataset) -> None:
    features = flight_geojson(_outcomes(demo), "xfeat")["features"]
    said = {
        (f["properties"]["kind"], f["properties"]["frame"]): f["properties"]["verdict"]
        for f in features
        if f["properties"]["kind"] in ("truth", "estimate")
    }
    assert said[("estimate", 1)] == "another tile, right fix"
    assert said[("estimate", 2)] == said[("estimate", 6)] == "wrong tile"
    assert said[("estimate", 5)] == "true tile, placed wrong"
    assert said[("truth", 3)] == "failed" and said[("truth", 4)] == "rightly raised"
    assert said[("estimate", 7)] == "matched"


def _settings_page(
    demo: FlightDataset, out: Path, lightglue: dict[str, Any], ran: dict[str, Any] | None = None
) -> str:
    """report.html written as a run writes it: the ``[lightglue]`` settings the run read
    (``lightglue_settings``, none where its strategy reads none) and its provenance ``ran``."""
    report = {
        "settings": {
            "min_inliers_threshold": 60,
            "max_keypoints": None,
            "stored_features": True,
            "geometric_prior": False,
            "options": {},
        },
        "keypoint_budget": 4096,
        "lightglue_settings": lightglue,
        "provenance": {"engines": {"extractor": {}}} if ran is None else ran,
        "matcher_labels": [],
    }
    mp = pytest.MonkeyPatch()
    mp.setattr(report_charts, "_png_uri", lambda fig: "data:,")
    mp.setattr(report_html, "gallery_pictures", lambda *a, **k: [])
    try:
        write_html_report(out, demo, [frame_outcome(0)], "xfeat", report)
    finally:
        mp.undo()
    text = (out / "report.html").read_text()
    return text[text.index("<h2>Settings and provenance</h2>") :]


def _table(page: str) -> dict[str, str]:
    return dict(re.findall(r"<tr><th>([^<]*)</th><td>([^<]*)</td></tr>", page))


def test_the_settings_read_in_the_product_s_words(demo: FlightDataset, tmp_path: Path) -> None:
    table = _settings_page(demo, tmp_path, {})
    rows = _table(table)
    assert rows["max_keypoints"] == "unset (strategy default: 4096)"
    assert rows["stored_features"] == "on" and rows["geometric_prior"] == "off"
    assert rows["options"] == "none"
    assert "None" not in rows.values() and "True" not in rows.values()
    # XFeat with mutual nearest neighbours (as the SIFT baseline) reads no [lightglue] setting
    assert not any(k.startswith("lightglue.") for k in rows)
    assert "<h3>[matcher] settings</h3>" in table


LIGHTGLUE_READ = {"mode": "auto", "depth_confidence": None}


def test_a_strategy_that_reads_lightglue_shows_its_settings(
    demo: FlightDataset, tmp_path: Path
) -> None:
    table = _settings_page(demo, tmp_path, LIGHTGLUE_READ)
    rows = _table(table)
    assert rows["lightglue.mode"] == "auto"
    assert rows["lightglue.depth_confidence"] == "unset (strategy default)"
    assert "<h3>[matcher] and [lightglue] settings</h3>" in table


def test_a_provenance_that_could_not_be_read_is_said_and_hides_no_setting(
    demo: FlightDataset, tmp_path: Path
) -> None:
    """The backend's provenance failed: the page says so (it showed "-" for the provider and
    nothing else), and the [lightglue] settings the run read are still shown (they were taken
    from the provenance's engines, which it no longer had)."""
    why = "provenance() raised RuntimeError: provenance unavailable"
    text = _settings_page(demo, tmp_path, LIGHTGLUE_READ, {"provenance_error": why})
    rows = _table(text)
    assert rows["provenance error"] == why
    assert rows["lightglue.mode"] == "auto"


def test_the_page_says_the_noise_put_on_the_attitudes(demo: FlightDataset, tmp_path: Path) -> None:
    noisy = with_attitude_noise(demo, 2.0)
    text, _ = drawn_report(tmp_path, noisy, [frame_outcome(0)])
    assert "<h1>Flight report: naip_demo with xfeat, attitude noise 2 deg (1 sigma)</h1>" in text


def _rows(out: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]


def test_a_real_replay_counts_and_shows_its_wrong_fixes(engine_dir: Path, tmp_path: Path) -> None:
    """15 frames at an inlier threshold of 8 without the geometric prior, frame 13 (no true tile)
    given only its first candidate (with its others, a rival elsewhere makes it ambiguous: no
    fix): picks of distractors kilometres off."""
    flight = tmp_path / "flight"
    shutil.copytree(DEMO, flight)
    rows = [json.loads(line) for line in (flight / "frames.jsonl").read_text().splitlines()]
    for row in rows:
        row["candidates"] = row["candidates"][:1] if row["index"] == 13 else row["candidates"]
    (flight / "frames.jsonl").write_text("".join(json.dumps(row) + "\n" for row in rows))
    out = tmp_path / "replay"
    settings = {
        "C3_MATCHER_MATCHER__MIN_INLIERS_THRESHOLD": "8",
        "C3_MATCHER_MATCHER__GEOMETRIC_PRIOR": "false",
    }
    args = ["replay", flight, "--strategy", "xfeat", "--limit", "15", "--out", out]
    proc = run_cli(*args, cwd=tmp_path, engine_dir=engine_dir, settings=settings, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    wrong = [
        r["index"]
        for r in _rows(out)
        if r["status"] == "ok" and (r["mean_error_px"] is None or r["mean_error_px"] > WRONG_FIX_PX)
    ]
    assert wrong, "no wrong fix to show"
    report = json.loads((out / "report.json").read_text())
    assert report["false_confident"] == len(wrong) and report["false_confident_frames"] == wrong
    assert f"  false-conf {len(wrong)}/15 frames: " in proc.stdout
    text = (out / "report.html").read_text()
    assert _kpis(text)["wrong fixes (false-confident)"] == f"{len(wrong)}/15"
    features = json.loads((out / "flight.geojson").read_text())["features"]
    judged = {
        f["properties"]["frame"]: f["properties"]["verdict"]
        for f in features
        if f["properties"]["kind"] == "estimate"
    }
    wrong_words = {"wrong tile", "true tile, placed wrong"}
    assert sorted(i for i, v in judged.items() if v in wrong_words) == wrong
    assert "lightglue." not in text and "<td>unset (strategy default: 4096)</td>" in text


def test_a_real_replay_counts_its_right_refusals_and_says_its_noise(
    engine_dir: Path, tmp_path: Path
) -> None:
    """Frames 12 (its true tile there), 13 and 14 (without) of the demo flight."""
    flight = tmp_path / "cut"
    (flight / "frames").mkdir(parents=True)
    for name in ("dataset.json", "calibration.json", "tiles.mbtiles"):
        shutil.copyfile(DEMO / name, flight / name)
    lines = (DEMO / "frames.jsonl").read_text().splitlines()[12:15]
    (flight / "frames.jsonl").write_text("\n".join(lines) + "\n")
    for line in lines:
        image = json.loads(line)["image"]
        shutil.copyfile(DEMO / image, flight / image)
    out = tmp_path / "replay"
    args = ["replay", flight, "--strategy", "xfeat", "--attitude-noise-deg", "1", "--out", out]
    proc = run_cli(*args, cwd=tmp_path, engine_dir=engine_dir, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    first = proc.stdout.splitlines()[0]
    assert first.endswith(", attitude noise 1 deg (1 sigma)"), first
    raised = [r["index"] for r in _rows(out) if r["status"] == "insufficient"]
    assert raised == [13, 14]  # the right answer where the true tile is absent
    text = (out / "report.html").read_text()
    assert "with xfeat, attitude noise 1 deg (1 sigma)</h1>" in text
    kpis = _kpis(text)
    assert kpis["rightly raised (true tile absent)"] == "2/2"
    assert kpis["failed (true tile present)"] == "0"
    assert text.count("R rightly raised (true tile absent)") == 2


def test_a_frame_whose_tiles_were_never_read_is_no_right_refusal() -> None:
    """A frame without its true tile that raised because the store gave none of its tiles (a
    damaged store) says nothing of the matcher: not the right answer, as C3-IT-05 leaves it out,
    so neither the verdict nor the summary counts it one."""
    from c3_matcher_tools.run.acceptance import Verdict, verdict
    from c3_matcher_tools.run.records import DroppedCandidate

    raised = frame_outcome(0, status=FrameStatus.INSUFFICIENT, true_present=False)
    unread = dataclasses.replace(
        raised,
        candidates=3,
        dropped=tuple(
            DroppedCandidate(i, None, "tile unreadable", "tile_decode TileDigestError")
            for i in range(3)
        ),
    )
    assert unread.no_tile_read
    assert verdict(raised) == Verdict.RIGHTLY_RAISED
    assert verdict(unread) == Verdict.FAILED
    assert summarize([raised]).absent_raised == 1
    assert summarize([unread]).absent_raised == 0
