"""A frame refused as ambiguous (``AmbiguousMatchError``: a rival candidate with nearly the best's
inliers places it elsewhere) is said to be ambiguous wherever a run's frames are counted or
shown: its ``results.jsonl`` line names the rival, ``replay``'s and ``eval``'s lines count it
apart from the frames with too few inliers, and the flight report's figures, table and legend
name it. It stays ``insufficient`` (it raised ``InsufficientInliersError``): C3-IT-05 counts it
raised where its true tile is absent. The run layer's mapping is checked on the shipped demo
flight (its store and images read) with a matcher that raises ``AmbiguousMatchError``."""

from __future__ import annotations

import io
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.errors import AmbiguousMatchError, InsufficientInliersError
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.eval_tables import print_flight_table
from c3_matcher_tools.replay import _report_lines
from c3_matcher_tools.run import FlightRun, FrameOutcome, StrategyEval, summarize
from c3_matcher_tools.run.acceptance import Verdict, metrics, verdict
from c3_matcher_tools.run.flight import run_flight
from c3_matcher_tools.run.records import FrameStatus
from c3_matcher_tools.run.scoring import result_fingerprint
from c3_matcher_tools.testing.outcomes import frame_outcome
from c3_matcher_tools.testing.report import drawn_report

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
RIVAL = "candidate 1 (700 inliers, 0.95 of the best's) places the frame 1112 m from candidate 0"


def _ambiguous(index: int, *, true_present: bool = True) -> FrameOutcome:
    """Frame ``index`` refused as ambiguous with 740 inliers on its best candidate."""
    raised = frame_outcome(index, status=FrameStatus.INSUFFICIENT, true_present=true_present)
    return replace(raised, insufficient_best=740, ambiguous=RIVAL)


def _outcomes() -> list[FrameOutcome]:
    """0: matched; 1, 2: ambiguous with the true tile present; 3: too few inliers; 4: ambiguous
    without its true tile."""
    return [
        frame_outcome(0),
        _ambiguous(1),
        _ambiguous(2),
        replace(frame_outcome(3, status=FrameStatus.INSUFFICIENT), insufficient_best=20),
        _ambiguous(4, true_present=False),
    ]


def test_the_results_line_names_the_rival_only_on_an_ambiguous_frame() -> None:
    plain, ambiguous = frame_outcome(0).to_json(), _ambiguous(1).to_json()
    assert "ambiguous" not in plain  # the other frames' keys as they were
    assert set(ambiguous) - set(plain) == {"ambiguous"}
    assert ambiguous["status"] == "insufficient" and ambiguous["ambiguous"] == RIVAL


def test_the_summary_counts_ambiguous_frames_among_those_raised() -> None:
    s = summarize(_outcomes())
    assert s.count(FrameStatus.INSUFFICIENT) == 4 and s.ambiguous_frames == (1, 2, 4)
    j = s.to_json()
    assert j["insufficient"] == 4 and j["ambiguous"] == 3 and j["ambiguous_frames"] == [1, 2, 4]
    # raising without the true tile is still the right answer (C3-IT-05)
    assert verdict(_outcomes()[4]) == Verdict.RIGHTLY_RAISED and s.absent_raised == 1
    assert metrics(_outcomes(), []).absent_raised.insufficient == 1


def test_replay_says_how_many_frames_were_ambiguous() -> None:
    report = {"strategy": "xfeat", "wall_s": 1.0, "startup_s": 0.1, "store": "tiles.mbtiles"}
    report |= {"results": "r", "fdr": "f", "geojson": "g", "html": None}
    said = "\n".join(_report_lines("f", report, summarize(_outcomes()), Path("out")))
    assert "  ok 1, insufficient inliers 1, ambiguous 3 (" in said, said
    assert ", backbone errors 0" in said
    plain = "\n".join(_report_lines("f", report, summarize(_outcomes()[:1]), Path("out")))
    assert "ambiguous" not in plain  # said only when a frame was


def test_eval_says_which_frames_each_strategy_found_ambiguous() -> None:
    outcomes = _outcomes()
    run = FlightRun("xfeat", {}, tuple(outcomes), 0.0, 0.0)
    row = StrategyEval(run, metrics(outcomes, outcomes), summarize(outcomes), None, None)
    stdout = io.StringIO()
    ctx: Any = type("Ctx", (), {"out": lambda self, text="": stdout.write(text + "\n")})()
    args: Any = type("Args", (), {"attitude_noise_deg": None})()
    report = {"frames": 5, "absent_frames": 1, "with_truth": True, "strategies": []}
    print_flight_table(ctx, args, "f", report, [row], Path("out"), None)
    said = stdout.getvalue()
    assert "xfeat: 3 frame(s) ambiguous, no fix" in said and "frames 1-2, 4" in said, said
    assert row.to_json()["per_frame"][1]["ambiguous"] == RIVAL
    assert "ambiguous" not in row.to_json()["per_frame"][0]


@pytest.fixture(scope="module")
def drawn(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, list[Any]]:
    """(report.html text, its figures) of the demo flight with :func:`_outcomes`."""
    return drawn_report(tmp_path_factory.mktemp("report"), load_dataset(DEMO), _outcomes())


def test_the_flight_report_names_ambiguous_frames(drawn: tuple[str, list[Any]]) -> None:
    text, figures = drawn
    rows = re.findall(r"<tr><td>(\d+)</td><td>(\w+)</td><td>(\d+)</td><td>([^<]*)</td>", text)
    table = {int(i): (status, int(inl), judged) for i, status, inl, judged in rows}
    assert table[1][:2] == ("ambiguous", 740) and table[3][:2] == ("insufficient", 20)
    assert table[1][2].startswith("F failed; ambiguous: candidate 1 (700 inliers")
    assert table[4][2].startswith("R rightly raised (true tile absent); ambiguous: ")
    assert "ambiguous (no fix: a rival candidate places the frame elsewhere)<b>3</b>" in text
    legend = re.sub(r"\s+", " ", text)
    assert "fewer inliers than the threshold, ambiguous, or an error" in legend
    labels = [
        t.get_text()
        for f in figures
        for a in f.axes
        if a.get_legend()
        for t in a.get_legend().get_texts()
    ]
    assert any(label.startswith("F or R over the threshold: ambiguous") for label in labels)


class _RaisesAmbiguous:
    """A matcher that finds every frame ambiguous: its best candidate with 740 inliers, the
    next one at another place with 700."""

    def match(self, nav: Any, rerank: Any, calibration: Any) -> Any:
        facts = (nav.frame_id, 740, 60, len(rerank.candidates), 0, "double")
        raise AmbiguousMatchError(*facts, ambiguity=RIVAL)


class _RaisesInsufficient:
    def match(self, nav: Any, rerank: Any, calibration: Any) -> Any:
        raise InsufficientInliersError(nav.frame_id, 12, 60, len(rerank.candidates), 0, "double")


def test_a_flight_records_a_frame_the_matcher_found_ambiguous_as_ambiguous() -> None:
    dataset = load_dataset(DEMO)
    (ambiguous,) = run_flight(_RaisesAmbiguous(), replace(dataset, frames=dataset.frames[:1]))
    assert ambiguous.status == FrameStatus.INSUFFICIENT and ambiguous.ambiguous == RIVAL
    assert ambiguous.candidate_inliers == 740 and "ambiguous" in str(ambiguous.error)
    assert ambiguous.to_json()["ambiguous"] == RIVAL
    (short,) = run_flight(_RaisesInsufficient(), replace(dataset, frames=dataset.frames[:1]))
    assert short.ambiguous is None and "ambiguous" not in short.to_json()


def test_the_geojson_names_the_rival_of_an_ambiguous_frame() -> None:
    from c3_matcher_tools.geojson import flight_geojson

    with_truth = [replace(o, truth_lat=40.0, truth_lon=-75.0) for o in _outcomes()]
    points = {
        f["properties"]["frame"]: f["properties"]
        for f in flight_geojson(with_truth, "xfeat")["features"]
        if f["properties"]["kind"] == "truth"
    }
    assert points[1]["ambiguous"] == RIVAL and points[1]["status"] == "insufficient"
    assert points[3]["ambiguous"] is None and points[0]["ambiguous"] is None


def test_a_rerun_whose_rival_changed_differs_in_its_fingerprint() -> None:
    """The determinism check (C3-IT-02) compares fingerprints: two runs refusing a frame as
    ambiguous against different rivals differ; a frame with too few inliers keeps its digest."""
    dataset = load_dataset(DEMO)
    one = replace(dataset, frames=dataset.frames[:1])
    (first,) = run_flight(_RaisesAmbiguous(), one)

    class _OtherRival(_RaisesAmbiguous):
        def match(self, nav: Any, rerank: Any, calibration: Any) -> Any:
            facts = (nav.frame_id, 740, 60, len(rerank.candidates), 0, "double")
            raise AmbiguousMatchError(*facts, ambiguity=RIVAL.replace("1112 m", "905 m"))

    (second,) = run_flight(_OtherRival(), one)
    (short,) = run_flight(_RaisesInsufficient(), one)
    assert first.fingerprint != second.fingerprint
    assert short.fingerprint == result_fingerprint(None, 12)
