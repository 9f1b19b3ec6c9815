"""What ``c3-matcher eval`` prints is true to what it measured: ``--json`` is one JSON document
whatever the number of datasets; a bar with nothing to measure is neither passed nor missed
(``"pass": null``, no '!'); a figure printed beside a bar never contradicts it; the summary
table's columns line up under their headers."""

from __future__ import annotations

import dataclasses
import json
import math
import random
import shutil
from pathlib import Path
from typing import Any, cast

import pytest

from c3_matcher.context import CommandContext
from c3_matcher_tools.eval_tables import print_summary_table, table_row
from c3_matcher_tools.evaluate import metrics
from c3_matcher_tools.run import FrameOutcome, StrategyEval, SummaryRow, summarize
from c3_matcher_tools.run.acceptance import Headline
from c3_matcher_tools.run.records import FlightRun
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.outcomes import frame_outcome

REPO = Path(__file__).resolve().parents[1]
FLIGHTS = REPO / "data" / "flights"


def _row(outcomes: list[FrameOutcome], run2: list[FrameOutcome] | None = None) -> str:
    m = metrics(outcomes, outcomes[:1] if run2 is None else run2)
    run = FlightRun("xfeat", {}, tuple(outcomes), 0.0, 0.0)
    timing = dataclasses.replace(summarize(outcomes), frame_ms_p50=10.0, frame_ms_p95=12.0)
    return table_row(StrategyEval(run, m, timing, "map.geojson", None))


class _Lines:
    def __init__(self) -> None:
        self.lines: list[str] = []

    def out(self, text: str = "") -> None:
        self.lines.append(text)


# -- a bar with nothing to measure ------------------------------------------------------------


def test_a_flight_without_true_tile_frames_leaves_its_true_tile_bars_unjudged() -> None:
    """naip_distractors_s2015's shape: every frame's true tile absent, every one refused."""
    run = [frame_outcome(i, status="insufficient", true_present=False) for i in range(12)]
    m = metrics(run, run[:1])
    assert m.inlier_count.passed is None and m.inlier_error.passed is None
    assert m.correct_tile.passed is None
    assert m.absent_raised.passed is True and m.false_confident.passed is True
    cells = _row(run).split()
    assert cells[1:6] == ["n/a", "same", "n/a", "0/0", "12/12"], cells  # no '!'


def test_a_flight_without_ground_truth_leaves_every_truth_bar_unjudged() -> None:
    """A recorded flight (``dataset import``): nothing to score against, not even IT-05's or
    false-confident's 0 of 0; only IT-02 (run twice) is measured, and an unmeasured bar
    never makes a run pass every bar."""
    run = [frame_outcome(i, true_present=False, has_truth=False) for i in range(5)]
    m = metrics(run, run[:1]).measures()
    unmeasured = ("C3-IT-01", "C3-IT-03", "C3-IT-04", "C3-IT-05", "false_confident")
    assert {k: m[k].passed for k in unmeasured} == dict.fromkeys(unmeasured)
    assert m["C3-IT-02"].passed is True
    assert not all(v.passed for v in m.values())
    assert "!" not in _row(run)
    assert _row(run, run2=[]).split()[2] == "n/a"  # IT-02 with no frame run twice


def test_a_measured_bar_that_is_missed_is_still_marked() -> None:
    run = [frame_outcome(0, inliers=60, error_px=3.0), frame_outcome(1, status="insufficient")]
    run.append(frame_outcome(2, true_present=False, error_px=400.0))  # an absent frame matched
    m = metrics(run, run[:1])
    assert [v.passed for v in m.measures().values()] == [False, True, False, False, False, False]
    cells = _row(run).split()
    assert cells[1] == "3!" and cells[3] == "3.00!" and cells[4] == "1/2!"
    assert cells[5:7] == ["0/1!", "1/3!"]


# -- figures beside their bars ----------------------------------------------------------------


def test_printed_figures_agree_with_their_bars() -> None:
    """IT-01 p5 is interpolated: inliers 79, 80 and 18 x 100 give p5 79.95, a miss, once
    printed "80!"; errors whose p95 is 2.496 px pass IT-03, once printed "2.50"."""
    inliers = [79, 80, *[100] * 18]
    errors = [*[1.0] * 18, 2.49, 2.61]
    run = [frame_outcome(i, inliers=n, error_px=e) for i, (n, e) in enumerate(zip(inliers, errors))]
    m = metrics(run, run[:1])
    assert m.inlier_count.p5_best_inliers == pytest.approx(79.95)
    assert m.inlier_error.p95_mean_error_px == pytest.approx(2.496)
    cells = _row(run).split()
    assert cells[1] == "79.9!" and float(cells[1][:-1]) < 80
    assert cells[3] == "2.496" and float(cells[3]) < 2.5


def test_the_all_flights_share_agrees_with_the_it04_bar() -> None:
    """35 of 37 correct tiles is 94.59 %, below IT-04's 0.95: once printed "95%"."""
    rows = [
        _summary("s2020_f2015", correct=18, present=19),
        _summary("s2015_f2020", correct=17, present=18),
    ]
    lines = _summary_lines(rows)
    assert "35/37 (94.5%) correct tile" in lines[-1], lines[-1]


def test_the_all_flights_line_of_distractor_only_flights_shows_no_share() -> None:
    lines = _summary_lines([_summary("naip_distractors_s2015"), _summary("naip_distractors")])
    assert "all flights" in lines[-1] and " - correct tile, 0/24 false-confident" in lines[-1]


def test_every_figure_printed_beside_a_bar_is_judged_as_its_value() -> None:
    from c3_matcher_tools.run.acceptance import IT01_BAR, IT03_BAR, IT04_BAR, Bar

    rng = random.Random(7)
    cases = [(IT01_BAR, 0, False), (IT03_BAR, 2, False), (IT04_BAR, 0, True)]
    cases += [(Bar("<=", 2.5), 2, False), (Bar(">", 80), 0, False), (Bar(">=", 0.955), 1, False)]
    for bar, decimals, percent in cases:
        values = [bar.limit * (1 + d) for d in (-1e-9, 0.0, 1e-9, -1e-3, 1e-3, -0.02, 0.02)]
        values += [bar.limit * rng.uniform(0.9, 1.1) for _ in range(2000)]
        for value in values:
            shown = bar.figure(value, decimals, percent=percent)
            printed = float(shown.rstrip("%")) / (100 if percent else 1)
            assert bar.judge(printed) == bar.judge(value), (bar, value, shown)
    assert IT03_BAR.figure(1.239, 2) == "1.24" and IT01_BAR.figure(301.7) == "302"  # as before
    assert IT01_BAR.figure(math.nan) == "n/a" and IT01_BAR.judge(math.nan) is None


# -- the summary table ------------------------------------------------------------------------


def _summary(flight: str, **figures: Any) -> SummaryRow:
    row = {"correct": 0, "present": 0, "it03_p95_px": math.nan, "it05_raised": 12}
    row |= {"absent": 12, "false_confident": 0, "scored": 12}
    return SummaryRow("xfeat", flight, Headline(**(row | figures)), 0, 600.0)


def _summary_lines(rows: list[SummaryRow]) -> list[str]:
    sink = _Lines()
    print_summary_table(cast(CommandContext, sink), rows)
    return sink.lines


def test_summary_values_are_right_justified_under_their_headers() -> None:
    lines = _summary_lines(
        [_summary("naip_distractors_s2015"), _summary("naip_demo", it05_raised=3, absent=3)]
    )
    header, rows = lines[1], lines[2:4]
    for title, values in (("IT-05", ("3/3", "12/12")), ("false-conf", ("0/12", "0/12"))):
        end = header.index(title) + len(title)
        for row, value in zip(rows, values, strict=True):
            assert row[end - len(value) : end] == value and row[end] == " ", (title, row)


# -- --json: one document ---------------------------------------------------------------------


def test_json_for_one_dataset_is_its_eval_json() -> None:
    from types import SimpleNamespace

    from c3_matcher_tools.eval_end import EvalRun
    from c3_matcher_tools.run.evaluation import SummaryRow

    report = {"dataset": "d", "strategies": []}
    rows = SummaryRow.not_run(["e"], ["xfeat"])  # a stop came before the second flight
    said: list[str] = []
    ctx: Any = SimpleNamespace(out=said.append)
    EvalRun(["d"], [], ["xfeat"], several=False, reports=[report]).show(ctx, as_json=True)
    run = EvalRun(["d", "e"], [], ["xfeat"], several=True, summary=rows, reports=[report])
    run.show(ctx, as_json=True)
    assert json.loads(said[0]) == report
    assert json.loads(said[1]) == {"flights": [report], "summary": [rows[0].to_json()]}


@pytest.mark.slow
def test_json_for_several_datasets_is_one_document_with_the_summary(
    engine_dir: Path, tmp_path: Path
) -> None:
    """Two shipped distractor-only flights cut to 3 frames each, xfeat: stdout parses as one
    JSON document, ``{"flights": [each eval.json], "summary": summary.json's rows}``."""
    flights = []
    for name in ("naip_distractors_s2015", "naip_distractors_s2010"):
        flight = shutil.copytree(FLIGHTS / name, tmp_path / name)
        lines = (flight / "frames.jsonl").read_text().splitlines()[:3]
        (flight / "frames.jsonl").write_text("\n".join(lines) + "\n")
        flights.append(flight)
    out = tmp_path / "eval"
    quick = ("--no-baseline", "--determinism-frames", "1", "--samples", "0")
    argv: tuple[str | Path, ...] = ("eval", *flights, "--strategy", "xfeat", *quick, "--out", out)
    proc = run_cli(*argv, "--json", cwd=REPO, engine_dir=engine_dir)
    assert proc.returncode == 0, proc.stderr[-3000:]
    document = json.loads(proc.stdout)
    assert set(document) == {"flights", "summary"}
    assert document["summary"] == json.loads((out / "summary.json").read_text())
    for report, flight in zip(document["flights"], flights, strict=True):
        assert report == json.loads((out / flight.name / "eval.json").read_text())
        (row,) = report["strategies"]
        passes = {k: v["pass"] for k, v in row["metrics"].items()}
        assert passes["C3-IT-01"] is None and passes["C3-IT-04"] is None, passes
        assert passes["C3-IT-05"] is True
    assert [s["flight"] for s in document["summary"]] == [f.name for f in flights]
