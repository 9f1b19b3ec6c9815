"""eval's inliers.png and error.png can be read frame by frame: the x axis is ticked with the
frame numbers (every k-th on a long flight), the dashed bar has a legend entry naming C3-IT-01's
or C3-IT-03's bar, a frame without a value is drawn apart, below value 0 in a row of its own
strategy (never as a 0 px error, never over another strategy's mark) and named in the legend,
and frames whose true tile is absent are banded grey as the flight report bands them. On
synthetic runs and on a real eval of three frames of the demo flight (two without their true
tile)."""

from __future__ import annotations

import dataclasses
import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from c3_matcher_tools import plots
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.run import FlightRun
from c3_matcher_tools.run.records import FrameStatus
from c3_matcher_tools.testing.outcomes import frame_outcome

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
ABSENT_GREY = (224, 224, 224)  # #bbbbbb at alpha 0.45 over white: the flight report's band


@dataclass
class Drawn:
    """What a chart drew: each text with where it starts, each marker (kind, centre, colour)
    and each filled dot (a finite value) with its centre."""

    texts: list[tuple[str, tuple[int, int]]] = field(default_factory=list)
    markers: list[tuple[int, tuple[int, int], tuple[int, ...]]] = field(default_factory=list)
    dots: list[tuple[tuple[int, int], tuple[int, ...]]] = field(default_factory=list)

    def text(self) -> list[str]:
        return [t for t, _ in self.texts]

    def crosses(self) -> list[tuple[tuple[int, int], tuple[int, ...]]]:
        """The 'x' marks drawn in the plot (x 70..730 of 900 px; the legend's is right of it)."""
        return [
            (at, c)
            for kind, at, c in self.markers
            if kind == cv2.MARKER_TILTED_CROSS and at[0] <= 730
        ]


def _record(monkeypatch: pytest.MonkeyPatch, charts: dict[str, Drawn], out: Path) -> None:
    """Record what every chart written under ``out`` draws, keyed by its file name."""
    current = Drawn()
    put_text, draw_marker, circle, write_png = (
        cv2.putText,
        cv2.drawMarker,
        cv2.circle,
        plots.write_png,
    )

    def text(canvas: Any, s: str, at: Any, *args: Any) -> Any:
        current.texts.append((s, tuple(at)))
        return put_text(canvas, s, at, *args)

    def marker(canvas: Any, at: Any, colour: Any, kind: int, *args: Any) -> Any:
        current.markers.append((kind, tuple(at), tuple(colour)))
        return draw_marker(canvas, at, colour, kind, *args)

    def dot(canvas: Any, at: Any, radius: int, colour: Any, *args: Any) -> Any:
        current.dots.append((tuple(at), tuple(colour)))
        return circle(canvas, at, radius, colour, *args)

    def written(image: Any, path: Path) -> Path:
        nonlocal current
        charts[Path(path).name] = current
        current = Drawn()
        return write_png(image, path)

    monkeypatch.setattr(plots.cv2, "putText", text)
    monkeypatch.setattr(plots.cv2, "drawMarker", marker)
    monkeypatch.setattr(plots.cv2, "circle", dot)
    monkeypatch.setattr(plots, "write_png", written)


def _runs() -> list[FlightRun]:
    """Two strategies over frames 0..5: frame 2 raised by both, frame 4 without its true tile
    (raised by both, rightly), frame 1 at 0.0 px for ``a`` (a perfect error)."""
    runs = []
    for strategy, error in (("a", 0.0), ("b", 1.0)):
        outcomes = [frame_outcome(i, error_px=1.5) for i in range(6)]
        outcomes[1] = frame_outcome(1, error_px=error)
        outcomes[2] = dataclasses.replace(
            frame_outcome(2, status=FrameStatus.INSUFFICIENT), insufficient_best=30
        )
        outcomes[4] = frame_outcome(4, status=FrameStatus.INSUFFICIENT, true_present=False)
        runs.append(FlightRun(strategy, {}, tuple(outcomes), 0.0, 0.0))
    return runs


def _charts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, runs: list[FlightRun]
) -> dict[str, Drawn]:
    charts: dict[str, Drawn] = {}
    _record(monkeypatch, charts, tmp_path)
    plots.eval_plots(load_dataset(DEMO), runs, tmp_path / "plots", samples=0)
    monkeypatch.undo()
    return charts


def _tick_labels(drawn: Drawn) -> list[str]:
    """The x tick labels: the numbers written under the plot (x 70..730 of 900 px; the value
    labels are left of it, the legend right of it)."""
    return [s for s, (x, y) in drawn.texts if s.isdigit() and 50 <= x < 750 and y > 300]


def test_the_frames_are_ticked_with_their_numbers(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    charts = _charts(tmp_path, monkeypatch, _runs())
    for name in ("inliers.png", "error.png"):
        assert _tick_labels(charts[name]) == [str(i) for i in range(6)], name


def test_the_bar_and_the_marks_are_named_in_the_legend(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    charts = _charts(tmp_path, monkeypatch, _runs())
    inliers, error = charts["inliers.png"].text(), charts["error.png"].text()
    assert "IT-01 bar 80" in inliers and "IT-03 bar 2.5 px" in error
    assert "raised / no value" in error and "raised / no value" not in inliers
    assert "true tile absent" in inliers and "true tile absent" in error


def test_a_frame_without_an_error_is_drawn_below_0_px_in_its_strategys_row(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    drawn = _charts(tmp_path, monkeypatch, _runs())["error.png"]
    perfect = [y for (_, y), _ in drawn.dots]
    crosses = drawn.crosses()
    assert len(crosses) == 4  # frames 2 and 4, each strategy
    assert min(y for (_, y), _ in crosses) > max(perfect)  # below the 0.0 px frame's dot
    by_colour: dict[tuple[int, ...], set[int]] = {}
    for (_, y), colour in crosses:
        by_colour.setdefault(colour, set()).add(y)
    rows = [ys.pop() for ys in by_colour.values() if len(ys) == 1]
    assert len(rows) == 2 and rows[0] != rows[1]  # a row each: one never hides the other


def test_frames_without_their_true_tile_are_banded_as_the_report_bands_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _charts(tmp_path, monkeypatch, _runs())
    image = cv2.imread(str(tmp_path / "plots" / "error.png"))
    assert image is not None
    # the plot spans x 70..730 of 900 px, six frames 132 px apart; y 60 is above every line
    absent_x, present_x = 70 + 132 * 4, 70 + 132 * 3 + 40
    assert tuple(int(c) for c in image[60, absent_x]) == ABSENT_GREY
    assert tuple(int(c) for c in image[60, present_x]) == (255, 255, 255)


def test_a_long_flights_ticks_are_thinned_to_round_frame_numbers(tmp_path: Path) -> None:
    drawn: dict[str, Drawn] = {}
    with pytest.MonkeyPatch.context() as mp:
        _record(mp, drawn, tmp_path)
        values = [float(i % 7) for i in range(400)]
        plots.line_chart(tmp_path / "long.png", {"a": values}, title="t", ylabel="px")
    labels = [int(s) for s in _tick_labels(drawn["long.png"])]
    assert labels[0] == 0 and 8 <= len(labels) <= 25
    step = labels[1] - labels[0]
    assert step in (20, 50) and labels == list(range(0, 400, step))


def _three_frames(where: Path) -> Path:
    """Frames 12 to 14 of the demo flight (13 and 14 without their true tile), as a flight."""
    where.mkdir()
    for file in ("calibration.json", "tiles.mbtiles"):
        shutil.copyfile(DEMO / file, where / file)
    meta = json.loads((DEMO / "dataset.json").read_text())
    meta["absent_frames"] = [13, 14]
    (where / "dataset.json").write_text(json.dumps(meta))
    lines = (DEMO / "frames.jsonl").read_text().splitlines()[12:15]
    (where / "frames.jsonl").write_text("\n".join(lines) + "\n")
    (where / "frames").mkdir()
    for line in lines:
        image = json.loads(line)["image"]
        shutil.copyfile(DEMO / image, where / image)
    return where


def test_a_real_eval_ticks_its_frames_and_draws_its_refusals_apart(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from c3_matcher.cli import main

    flight = _three_frames(tmp_path / "flight")
    charts: dict[str, Drawn] = {}
    _record(monkeypatch, charts, tmp_path)
    args = ["--strategy", "sift_magsac", "--determinism-frames", "1", "--samples", "0"]
    assert main(["eval", str(flight), "--out", str(tmp_path / "out"), *args]) == 0
    monkeypatch.undo()
    error = charts["error.png"]
    assert _tick_labels(error) == ["12", "13", "14"]
    assert {"IT-03 bar 2.5 px", "raised / no value", "true tile absent"} <= set(error.text())
    assert "IT-01 bar 80" in charts["inliers.png"].text()
    report = json.loads((tmp_path / "out" / "eval.json").read_text())
    frames = report["strategies"][0]["per_frame"]
    unmatched = [f["index"] for f in frames if f["mean_error_px"] is None]
    assert {13, 14} <= set(unmatched)  # the right refusals, drawn apart (one 'x' each)
    assert len(error.crosses()) == len(unmatched)
    zero_px = [y for (_, y), _ in error.dots]
    assert all(y > max(zero_px, default=0) for (_, y), _ in error.crosses())
    image = cv2.imread(str(tmp_path / "out" / "error.png"))
    assert image is not None and tuple(int(c) for c in image[60, 70 + 330]) == ABSENT_GREY
    assert np.array_equal(image[60, 70 + 100], (255, 255, 255))


def test_more_frame_numbers_than_frames_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="3 frames for a chart of 2 frames"):
        plots.line_chart(
            tmp_path / "c.png", {"a": [1.0, 2.0]}, title="t", ylabel="px", frames=[4, 5, 6]
        )
