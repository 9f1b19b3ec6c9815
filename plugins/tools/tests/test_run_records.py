"""A run's summary and its C3-IT measures are typed records whose JSON forms are what
``report.json``, ``eval.json`` and ``summary.json`` hold: the counts by status flattened after
``frames``, each measure's ``"pass"`` after its figures and judged from them."""

from __future__ import annotations

import json
import math
from dataclasses import replace

from c3_matcher_tools.run import FlightRun, StrategyEval, SummaryRow, summarize
from c3_matcher_tools.run.acceptance import metrics
from c3_matcher_tools.run.records import FrameStatus
from c3_matcher_tools.testing.outcomes import frame_outcome


def test_a_summary_in_json_counts_every_status_right_after_frames() -> None:
    outcomes = [
        frame_outcome(0),
        frame_outcome(1, status=FrameStatus.INSUFFICIENT),
        frame_outcome(2, status=FrameStatus.UNREADABLE),
        frame_outcome(3, status=FrameStatus.UNREADABLE),
    ]
    s = summarize(outcomes)
    assert s.frames == 4 and s.failed == 3 and s.count(FrameStatus.UNREADABLE) == 2
    j = s.to_json()
    statuses = [str(x) for x in FrameStatus]
    assert list(j)[: 1 + len(statuses)] == ["frames", *statuses]
    assert [j[x] for x in statuses] == [s.count(x) for x in FrameStatus] == [1, 1, 0, 2]
    assert json.loads(json.dumps(j)) == j  # plain JSON: lists, not tuples


def test_a_summary_of_no_frame_has_no_percentile() -> None:
    s = summarize([])
    assert s.frames == 0 and s.frame_ms_p50 is None and s.position_error_m_p95 is None
    assert s.to_json()["total_s"] == 0.0


def test_each_measure_is_judged_from_its_own_figures_and_says_so_last() -> None:
    run = [frame_outcome(0, inliers=50), frame_outcome(1, inliers=300, error_px=3.0)]
    run.append(frame_outcome(2, status=FrameStatus.INSUFFICIENT, true_present=False))
    m = metrics(run, run[:2])
    assert m.inlier_count.passed is False  # p5 of (50, 300) is below 80
    assert m.inlier_error.passed is False  # p95 of (1, 3) px is above 2.5
    assert m.absent_raised.passed is True and m.determinism.passed is True
    for name, measure in m.to_json().items():
        assert list(measure)[-1] == "pass", name
        assert measure["pass"] is m.measures()[name].passed
    h = m.headline
    assert (h.correct, h.present, h.it05_raised, h.absent) == (2, 2, 1, 1)


def test_a_summary_row_is_the_headline_or_the_error() -> None:
    outcomes = [frame_outcome(0), frame_outcome(1)]
    run = FlightRun("xfeat", {}, tuple(outcomes), 0.0, 0.0)
    evaluated = StrategyEval(run, metrics(outcomes, []), summarize(outcomes), "g", None)
    row = SummaryRow.of("f", evaluated).to_json()
    assert row["strategy"] == "xfeat" and row["flight"] == "f" and row["correct"] == 2
    assert math.isclose(row["it03_p95_px"], 1.0) and row["frame_ms_p50"] == 10.0
    failed = SummaryRow("xfeat", "f", error="no engine").to_json()
    assert failed == {"strategy": "xfeat", "flight": "f", "error": "no engine"}


def test_frame_times_are_those_of_the_frames_the_matcher_ran_on() -> None:
    """An unreadable image never reaches the matcher: its 0 ms must not pull the latency
    figures down."""
    ran = [replace(frame_outcome(i), elapsed_ms=ms) for i, ms in ((0, 500.0), (1, 520.0))]
    unreadable = [
        replace(frame_outcome(i, status=FrameStatus.UNREADABLE), elapsed_ms=0.0) for i in (2, 3)
    ]
    s = summarize([*ran, *unreadable])
    assert (s.frame_ms_p50, s.frame_ms_mean, s.total_s) == (510.0, 510.0, 1.02)
    assert summarize(unreadable).frame_ms_p50 is None


def test_the_correct_tile_count_is_over_the_frames_c3_it_04_scores() -> None:
    """A frame without ground truth (its candidates only partly labelled) is left out of the
    summary's correct-tile count as it is out of C3-IT-04: the report and eval.json agree."""
    outcomes = [frame_outcome(0), frame_outcome(1), frame_outcome(2, has_truth=False)]
    s, h = summarize(outcomes), metrics(outcomes, []).headline
    assert (s.true_present, s.correct_candidate) == (h.present, h.correct) == (2, 2)


def test_the_gnss_good_figure_is_over_frames_whose_log_says_gnss_was_good() -> None:
    """A frame whose log states no GNSS quality (``gnss_degraded`` None) was counted as one of
    good GNSS: the figure now holds only the frames the log says were good."""
    near = dict(telemetry_lat=0.0, telemetry_lon=0.0)
    outcomes = [
        replace(frame_outcome(0), **near, telemetry_error_m=2.0, gnss_degraded=False),
        replace(frame_outcome(1), **near, telemetry_error_m=4.0, gnss_degraded=False),
        replace(frame_outcome(2), **near, telemetry_error_m=90.0, gnss_degraded=None),
        replace(frame_outcome(3), **near, telemetry_error_m=50.0, gnss_degraded=True),
    ]
    s = summarize(outcomes)
    assert (s.with_telemetry, s.gnss_degraded_frames) == (4, (3,))
    assert s.telemetry_error_m_p50_gnss_good == 3.0
    unstated = [replace(o, gnss_degraded=None) for o in outcomes]
    assert summarize(unstated).telemetry_error_m_p50_gnss_good is None


def test_a_frame_whose_image_could_not_be_read_counts_in_no_it_measure() -> None:
    """An unreadable frame (the camera's loss) was a true-tile frame with 0 inliers: it dragged
    IT-01's p5 to 0 and IT-04 below its bar for a matcher right on every readable frame."""
    lost = FrameStatus.UNREADABLE
    run = [frame_outcome(i, inliers=90) for i in range(4)]
    run += [frame_outcome(4, status=lost), frame_outcome(5, status=lost, true_present=False)]
    run.append(frame_outcome(6, status=FrameStatus.INSUFFICIENT, true_present=False))
    m = metrics(run, [])
    assert (m.inlier_count.p5_best_inliers, m.inlier_count.frames) == (90.0, 4)
    assert (m.correct_tile.correct, m.correct_tile.frames, m.correct_tile.passed) == (4, 4, True)
    assert (m.absent_raised.insufficient, m.absent_raised.absent_frames) == (1, 1)
    assert m.false_confident.of == 5


def test_eval_forgets_its_own_match_pictures_and_nothing_else(tmp_path) -> None:
    """An eval removed the whole ``matches/`` folder of its output, a user's notes in it too."""
    from c3_matcher_tools.plots import MATCH_PICTURES, forget_match_pictures

    folder = tmp_path / MATCH_PICTURES
    folder.mkdir()
    for name in ("disk_lightglue_0003.png", "xfeat_0012.png", "notes.txt", "map.png"):
        (folder / name).write_text("x")
    forget_match_pictures(tmp_path)
    assert sorted(p.name for p in folder.iterdir()) == ["map.png", "notes.txt"]
    (folder / "notes.txt").unlink()
    (folder / "map.png").unlink()
    (folder / "xfeat_0001.png").write_text("x")
    forget_match_pictures(tmp_path)
    assert not folder.exists()  # its own pictures only: the folder goes with them
