"""The flight report of a recorded flight (no ground truth): it draws the vehicle's GNSS track and
where the telemetry says each frame looks beside the estimate, reports the estimate minus the
telemetry position with the GNSS accuracy the log states, marks frames whose GNSS was degraded; its
legends never cover a bar or the inlier threshold; the chart and the table use the same word for a
failed frame; "made by" is the whole JSON; a frame whose attitude was assumed level is marked, its
look point joined to its estimate by no red error segment. The flight is imported from a PX4 ULog
over the demo frames; outcomes are set per frame (no engine run here)."""

from __future__ import annotations

import dataclasses
import html as html_lib
import json
import math
import re
import shutil
import uuid
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.serialize import load_calibration
from c3_matcher_tools.dataset.format import FlightDataset, load_dataset
from c3_matcher_tools.dataset.sources.images import folder_shots
from c3_matcher_tools.dataset.sources.options import ImportOptions, ProposalOptions
from c3_matcher_tools.dataset.sources.ulog import read_ulog
from c3_matcher_tools.dataset.sources.writer import write_imported_flight
from c3_matcher_tools.report.trajectory import ASSUMED_LABEL, GREY, RED
from c3_matcher_tools.run import (
    FrameOutcome,
    summarize,
    telemetry_reference,
)
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog
from c3_matcher_tools.testing.report import drawn_report

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> FlightDataset:
    root = tmp_path_factory.mktemp("recorded")
    poses = fl.flight_poses(DEMO, range(5))
    log = write_ulog(root / "flight.ulg", poses, flaws=("gnss_loss",))
    images = root / "images"
    images.mkdir()
    for i, p in enumerate(poses):
        shutil.copyfile(p.image, images / f"IMG_{i:04d}.jpg")
    proposal = ProposalOptions(DEMO / "tiles.mbtiles")
    options = ImportOptions(load_calibration(DEMO / "calibration.json"), proposal)
    write_imported_flight(read_ulog(log), folder_shots(images), options, root / "flight")
    return load_dataset(root / "flight")


def _outcomes(dataset: FlightDataset) -> list[FrameOutcome]:
    """Frame 3 failed; the others located 2 m north of their telemetry look point."""
    out = []
    for f in dataset.frames:
        ref = telemetry_reference(f)
        assert ref is not None
        ok = f.index != 3
        est_lat = ref.lat + 2.0 / 111_320.0
        out.append(
            FrameOutcome(
                f.index, str(uuid.uuid4()), "ok" if ok else "insufficient", 500.0, False,
                120 if ok else 0, 0 if ok else None, False, math.nan, 0.5 if ok else math.nan,
                "", None if ok else "insufficient inliers", None, has_truth=False,
                est_lat=est_lat if ok else None, est_lon=ref.lon if ok else None,
                telemetry_error_m=2.0 if ok else math.nan, insufficient_best=0 if ok else 31,
                telemetry_lat=ref.lat, telemetry_lon=ref.lon,
                gnss_accuracy_m=ref.gnss_accuracy_m, gnss_degraded=ref.gnss_degraded,
            )
        )  # fmt: skip
    return out


@pytest.fixture(scope="module")
def drawn(
    recorded: FlightDataset, tmp_path_factory: pytest.TempPathFactory
) -> tuple[str, list[Any]]:
    """(report.html text, the matplotlib figures it embeds, in order)."""
    return drawn_report(tmp_path_factory.mktemp("report"), recorded, _outcomes(recorded))


def test_summary_reports_estimate_minus_telemetry(recorded: FlightDataset) -> None:
    s = summarize(_outcomes(recorded))
    assert s.with_truth == 0 and s.with_telemetry == 5
    assert s.telemetry_error_m_p50 == pytest.approx(2.0)
    assert s.gnss_accuracy_m_p50 == pytest.approx(1.5)
    assert s.gnss_degraded_frames == (1,)
    assert s.to_json()["gnss_degraded_frames"] == [1]


def test_no_truth_report_draws_the_telemetry_and_gnss_tracks(drawn: tuple[str, list[Any]]) -> None:
    text, figures = drawn
    trajectory = figures[0].axes[0]
    labels = {line.get_label() for line in trajectory.get_lines()}
    assert {"vehicle GNSS track", "telemetry: where the frame looks", "estimate"} <= labels
    legend = {t.get_text() for t in trajectory.get_legend().get_texts()}
    assert "GNSS absent or degraded" in legend and "failed frame (telemetry)" in legend
    assert "telemetry vs estimate" in trajectory.get_title()
    assert "estimate - telemetry p50 / p95 (m)" in text
    per_frame = figures[1].axes[1]
    assert "estimate - telemetry" in {line.get_label() for line in per_frame.get_lines()}
    assert "GNSS accuracy (log)" in {line.get_label() for line in per_frame.get_lines()}


def test_legends_cover_no_bar_and_no_threshold(drawn: tuple[str, list[Any]]) -> None:
    _, figures = drawn
    for fig in figures:
        renderer = fig.canvas.get_renderer()
        plots = [ax.get_window_extent(renderer) for ax in fig.axes]
        legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
        assert legends
        for legend in legends:
            box = legend.get_window_extent(renderer)
            for plot in plots:
                assert not box.overlaps(plot), (box, plot)


def test_chart_and_table_use_one_word_for_failed_frames(drawn: tuple[str, list[Any]]) -> None:
    text, figures = drawn
    inliers = figures[1].axes[0]
    legend = [t.get_text() for t in inliers.get_legend().get_texts()]
    assert "F: failed" in legend and "60 inliers threshold" in legend
    assert [t.get_text() for t in inliers.texts] == ["F"]  # frame 3
    rows = re.findall(r"<tr><td>(\d+)</td><td>(\w+)</td><td>\d+</td><td>([^<]*)</td>", text)
    verdicts = {int(i): v for i, _, v in rows}
    assert verdicts[3] == "F failed" and verdicts[0] == "matched"
    assert "WRONG" not in text and "FAILED" not in text


def test_made_by_is_whole_json(drawn: tuple[str, list[Any]], recorded: FlightDataset) -> None:
    text, _ = drawn
    cell = re.search(r"<th>made by</th><td>(.*?)</td>", text, re.S)
    assert cell is not None
    assert json.loads(html_lib.unescape(cell.group(1))) == recorded.meta["spec"]


def test_frames_of_an_assumed_attitude_are_marked_not_drawn_as_errors(
    recorded: FlightDataset, tmp_path: Path
) -> None:
    """Frame 4's attitude assumed level: its look point marked, its segment dashed grey."""
    outcomes = [dataclasses.replace(o, attitude_assumed=o.index == 4) for o in _outcomes(recorded)]
    _, figures = drawn_report(tmp_path, recorded, outcomes)
    trajectory = figures[0].axes[0]
    marked = {c.get_label(): len(c.get_offsets()) for c in trajectory.collections}
    assert marked[ASSUMED_LABEL] == 1
    segments = [line for line in trajectory.get_lines() if len(line.get_xdata()) == 2]
    red = [line for line in segments if line.get_color() == RED]
    grey = [line for line in segments if line.get_color() == GREY]
    assert len(red) == 3 and len(grey) == 1  # frames 0-2; frame 4; frame 3 failed
    assert grey[0].get_linestyle() == "--" and red[0].get_linestyle() == "-"
