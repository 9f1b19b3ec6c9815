"""Text from data is drawn as it is, never parsed as math: a dataset named ``demo $^^$ x`` (a
legal name) titles its trajectory with those characters, where matplotlib would otherwise read
``$^^$`` as mathtext, fail to parse it and end replay with an internal error after every frame
ran (eval recording the strategy as failed)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from c3_matcher_tools.dataset.format import FlightDataset, load_dataset
from c3_matcher_tools.report import trajectory
from c3_matcher_tools.report.charts import per_frame_figure, trajectory_figure
from c3_matcher_tools.run import FrameOutcome, truth_position
from c3_matcher_tools.testing.outcomes import frame_outcome
from c3_matcher_tools.testing.report import drawn_report

from .conftest import C3, DEMO, SmallFlight

NAME = "demo $^^$ x"
"""A name mathtext cannot parse (the reported one)."""


def _named(name: str) -> FlightDataset:
    """The shipped demo flight named ``name``."""
    demo = load_dataset(DEMO)
    return dataclasses.replace(demo, meta={**demo.meta, "name": name})


def _outcomes(dataset: FlightDataset) -> list[FrameOutcome]:
    """Three frames matched where they truly look, 2 m north of it."""
    outcomes = []
    for frame in dataset.frames[:3]:
        truth = truth_position(dataset, frame)
        assert truth is not None
        where = {"truth_lat": truth[0], "truth_lon": truth[1]}
        estimate = {"est_lat": truth[0] + 2 / 111_320.0, "est_lon": truth[1]}
        outcomes.append(dataclasses.replace(frame_outcome(frame.index), **where, **estimate))
    return outcomes


def test_a_trajectory_titled_with_dollars_draws_them_as_text() -> None:
    dataset = _named(NAME)
    fig = Figure()
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    trajectory.draw_trajectory(ax, dataset, _outcomes(dataset), f"{NAME}: truth vs estimate")
    fig.canvas.draw()  # where mathtext raised
    assert ax.get_title() == f"{NAME}: truth vs estimate"
    assert not ax.title.get_parse_math()


def test_the_report_charts_of_a_flight_named_with_dollars_are_drawn(tmp_path: Path) -> None:
    dataset = _named(NAME)
    outcomes = _outcomes(dataset)
    assert trajectory_figure(dataset, outcomes, NAME).startswith("data:image/png;base64,")
    assert per_frame_figure(outcomes, 60).startswith("data:image/png;base64,")
    page, figures = drawn_report(tmp_path, dataset, outcomes)
    assert "demo $^^$ x" in page and len(figures) == 2


def test_replay_of_a_flight_named_with_dollars_writes_its_report(
    tmp_path: Path, small_flight: SmallFlight, c3: C3
) -> None:
    flight, out = small_flight(NAME), tmp_path / "out"
    done = c3("replay", str(flight), "--strategy", "sift_magsac", "--out", str(out), "--json")
    assert done.returncode == 0, done.stderr
    assert "internal error" not in done.stderr, done.stderr
    assert json.loads((out / "report.json").read_text())["frames"] == 2
    assert (out / "report.html").read_text().startswith("<!DOCTYPE html>")
