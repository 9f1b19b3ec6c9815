"""Plots drawn with OpenCV (matplotlib is not a dependency): per-frame line charts, and the
pictures ``eval`` draws of its runs (:func:`eval_plots`)."""

from __future__ import annotations

import contextlib
import itertools
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.viz import draw_matches, write_png
from c3_matcher_tools.run.acceptance import IT01_BAR, IT03_BAR, it01_inliers

if TYPE_CHECKING:
    from c3_matcher_tools.dataset.format import FlightDataset, FrameRecord
    from c3_matcher_tools.run.records import FlightRun, FrameOutcome

__all__ = ["CHARTS", "MATCH_PICTURES", "eval_plots", "forget_match_pictures", "line_chart"]

CHARTS = ("inliers", "error")
"""The charts :func:`eval_plots` writes in its output directory (``<name>.png``)."""
MATCH_PICTURES = "matches"
"""The folder of its output directory where :func:`eval_plots` draws the sampled frames'
matches (``<strategy>_<frame>.png``)."""

_COLOURS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189))
_BAR_COLOUR = (0, 0, 200)  # BGR, as the canvas is drawn
_ABSENT = ((187, 187, 187), 0.45)
"""Frames whose true tile is absent: the flight report's band (``report/charts.py``: #bbbbbb at
alpha 0.45), so the right refusals read alike in both."""
_Key = tuple[int, int, int] | Literal["bar", "no value", "shaded", "marked"]
_Entry = tuple[tuple[str, ...], _Key]
"""A legend entry: its lines of text, and what it explains: a series (its colour), the bar,
a frame without a value, the absent-tile band, or a marked point."""
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_BLACK = (0, 0, 0)
_TICK_GAP_PX = 12
"""The least gap between two x tick labels: on a long flight every k-th frame is labelled."""
_NO_VALUE_ROW_PX = 8
"""The height of each series' row in the band below the axis where frames without a value
are drawn."""


@dataclass(frozen=True)
class _Plot:
    """Where a chart draws: the canvas size, the margins around the plot, the number of frames
    (x: their positions, 0 .. n-1), the value at the plot's top, and the height of the band
    below value 0 where each series' frames without a value are drawn (0: none has one)."""

    w: int
    h: int
    n: int
    y_max: float
    band: int
    left: int = 70
    right: int = 170
    top: int = 40
    bottom: int = 50

    @property
    def right_edge(self) -> int:
        return self.w - self.right

    @property
    def floor(self) -> int:
        """The y of the plot's bottom edge (the band's bottom)."""
        return self.h - self.bottom

    def x(self, i: float) -> int:
        return round(self.left + (self.right_edge - self.left) * (i / max(self.n - 1, 1)))

    def px(self, i: float, v: float) -> tuple[int, int]:
        zero = self.floor - self.band
        return self.x(i), round(zero - (zero - self.top) * (v / self.y_max))

    def no_value_y(self, row: int) -> int:
        """The y of series ``row``'s frames without a value, in the band below value 0."""
        return self.floor - self.band + _NO_VALUE_ROW_PX * row + _NO_VALUE_ROW_PX // 2 + 2


def line_chart(
    out: Path,
    series: Mapping[str, Sequence[float]],
    *,
    title: str,
    ylabel: str,
    bar: float | None = None,
    bar_label: str = "bar",
    size: tuple[int, int] = (900, 420),
    marked: Mapping[str, Sequence[bool]] | None = None,
    marked_note: Sequence[str] = (),
    frames: Sequence[int] = (),
    shaded: Sequence[bool] = (),
    shaded_label: str = "true tile absent",
    no_value_label: str = "no value",
) -> Path:
    """Write a PNG line chart: one polyline per series over the frames (x, ticked with the
    frame numbers ``frames``, by default 0, 1, ..; every k-th on a long flight). A NaN value
    leaves a gap, and its frame is drawn as an 'x' in a band below value 0, a row a series, so
    that it never reads as a value of 0 nor hides another series' ('x' ``no_value_label`` in
    the legend). ``bar`` draws a dashed horizontal reference (``bar_label``); ``shaded``: per
    frame, whether it is banded grey (``shaded_label``); ``marked``: per series, the points
    ringed with a square, which the legend explains in the lines of ``marked_note``. More
    ``frames`` or ``shaded`` than the longest series has values: ValueError."""
    plot = _layout(series, bar, size, len(frames), len(shaded))
    no_value = plot.band > 0
    canvas = np.full((plot.h, plot.w, 3), 255, dtype=np.uint8)
    _axes(canvas, plot, frames or range(plot.n), shaded, no_value)
    marks = marked or {}
    legend: list[_Entry] = []
    if bar is not None:  # under the lines
        _dashed(canvas, plot.left, plot.right_edge, plot.px(0, bar)[1])
    for row, (label, values) in enumerate(series.items()):
        colour = _COLOURS[row % len(_COLOURS)][::-1]
        _polyline(canvas, plot, row, values, colour, marks.get(label, ()))
        legend.append(((label,), colour))
    if bar is not None:
        legend.append(((bar_label,), "bar"))
    if no_value:
        legend.append(((no_value_label,), "no value"))
    if any(shaded):
        legend.append(((shaded_label,), "shaded"))
    if any(any(m) for m in marks.values()):
        legend.append((tuple(marked_note), "marked"))
    _legend(canvas, (plot.right_edge, plot.top + 10), legend)
    cv2.putText(canvas, title, (plot.left, 25), _FONT, 0.6, _BLACK, 1)
    axis = f"{ylabel} / frame"
    cv2.putText(canvas, axis, (plot.left, plot.h - 8), _FONT, 0.45, _BLACK, 1)
    return write_png(canvas[:, :, ::-1], out)


def _layout(
    series: Mapping[str, Sequence[float]],
    bar: float | None,
    size: tuple[int, int],
    frames: int,
    shaded: int,
) -> _Plot:
    """Where a chart of ``series`` (and ``bar``) draws on a canvas of ``size``; ValueError where
    it is given more frame numbers (``frames``) or shadings (``shaded``) than frames."""
    n = max((len(s) for s in series.values()), default=1)
    for name, given in (("frames", frames), ("shaded", shaded)):
        if given > n:
            raise ValueError(f"line_chart: {given} {name} for a chart of {n} frames")
    finite = [v for s in series.values() for v in s if math.isfinite(v)]
    finite += [] if bar is None else [bar]
    no_value = any(not math.isfinite(v) for s in series.values() for v in s)
    return _Plot(
        *size,
        n,
        max(finite) * 1.1 if finite and max(finite) > 0 else 1.0,
        _NO_VALUE_ROW_PX * len(series) + 4 if no_value else 0,
    )


def _axes(
    canvas: NDArray[np.uint8],
    plot: _Plot,
    frames: Sequence[int],
    shaded: Sequence[bool],
    no_value: bool,
) -> None:
    """The grid and value labels (y), the shaded frames' bands, the frame ticks (x), the band
    for frames without a value, and the plot's frame."""
    for k in range(5):
        v = plot.y_max * k / 4
        _, y = plot.px(0, v)
        cv2.line(canvas, (plot.left - 4, y), (plot.right_edge, y), (225, 225, 225), 1)
        cv2.putText(canvas, f"{v:.3g}", (5, y + 4), _FONT, 0.4, _BLACK, 1)
    for i in (i for i, s in enumerate(shaded) if s):
        x0, x1 = max(plot.x(i - 0.5), plot.left), min(plot.x(i + 0.5), plot.right_edge)
        _shade(canvas, (x0, plot.top), (x1, plot.floor))
    step = _tick_step(frames, plot.right_edge - plot.left)
    for i in range(0, len(frames), step):
        x = plot.x(i)
        cv2.line(canvas, (x, plot.floor), (x, plot.floor + 4), _BLACK, 1)
        label = str(frames[i])
        (width, _), _ = cv2.getTextSize(label, _FONT, 0.4, 1)
        cv2.putText(canvas, label, (x - width // 2, plot.floor + 17), _FONT, 0.4, _BLACK, 1)
    if no_value:
        zero = plot.floor - plot.band
        cv2.line(canvas, (plot.left, zero), (plot.right_edge, zero), (160, 160, 160), 1)
        cv2.putText(canvas, "no value", (5, plot.floor - 2), _FONT, 0.35, _BLACK, 1)
    cv2.rectangle(canvas, (plot.left, plot.top), (plot.right_edge, plot.floor), _BLACK, 1)


def _tick_step(frames: Sequence[int], room_px: int) -> int:
    """Every how many frames the x axis is labelled: 1, 2, 5, 10, 20, 50, .. frames, the
    least that leaves each label (the widest of ``frames``'s) room to be read in ``room_px``."""
    widest = max((cv2.getTextSize(str(f), _FONT, 0.4, 1)[0][0] for f in frames), default=0)
    fits = max(room_px // (widest + _TICK_GAP_PX), 1)
    steps = (m * 10**e for e in itertools.count() for m in (1, 2, 5))
    return next(s for s in steps if -(-len(frames) // s) <= fits)


def _shade(canvas: NDArray[np.uint8], corner: tuple[int, int], opposite: tuple[int, int]) -> None:
    """The absent-tile band over the rectangle from ``corner`` to ``opposite``, laid over what
    is drawn there (:data:`_ABSENT`)."""
    (x0, y0), (x1, y1) = corner, opposite
    colour, alpha = _ABSENT
    region = canvas[y0 : y1 + 1, x0 : x1 + 1].astype(np.float64)
    blended = region * (1 - alpha) + np.asarray(colour, dtype=np.float64) * alpha
    canvas[y0 : y1 + 1, x0 : x1 + 1] = np.round(blended).astype(np.uint8)


def _dashed(canvas: NDArray[np.uint8], x0: int, x1: int, y: int) -> None:
    """The bar: a dashed horizontal line from ``x0`` to ``x1``."""
    for x in range(x0, x1, 12):
        cv2.line(canvas, (x, y), (min(x + 6, x1), y), _BAR_COLOUR, 1)


def _polyline(
    canvas: NDArray[np.uint8],
    plot: _Plot,
    row: int,
    values: Sequence[float],
    colour: tuple[int, int, int],
    marked: Sequence[bool] = (),
) -> None:
    """One series (the ``row``-th): a line through its finite values, an 'x' in its row of
    the band below value 0 for each NaN, a square around each ``marked`` point."""
    previous = None
    for i, v in enumerate(values):
        if not math.isfinite(v):
            cv2.drawMarker(
                canvas, (plot.x(i), plot.no_value_y(row)), colour, cv2.MARKER_TILTED_CROSS, 7, 1
            )
            previous = None
            continue
        p = plot.px(i, v)
        if previous is not None:
            cv2.line(canvas, previous, p, colour, 2, cv2.LINE_AA)
        cv2.circle(canvas, p, 2, colour, -1)
        if i < len(marked) and marked[i]:
            cv2.drawMarker(canvas, p, colour, cv2.MARKER_SQUARE, 11, 1)
        previous = p


def _legend(canvas: NDArray[np.uint8], at: tuple[int, int], entries: Sequence[_Entry]) -> None:
    """The legend right of the plot (whose right edge and first row ``at`` gives), an entry a
    row (a row a line of its text): a series' line in its colour, the bar's dashes, the 'x' of
    a frame without a value, the absent-tile band, or the square that rings marked points."""
    x, y = at
    for lines, key in entries:
        if key == "bar":
            _dashed(canvas, x + 10, x + 30, y)
        elif key == "no value":
            cv2.drawMarker(canvas, (x + 20, y), _BLACK, cv2.MARKER_TILTED_CROSS, 7, 1)
        elif key == "shaded":
            _shade(canvas, (x + 12, y - 6), (x + 28, y + 6))
        elif key == "marked":
            cv2.drawMarker(canvas, (x + 20, y), _BLACK, cv2.MARKER_SQUARE, 11, 1)
        else:
            cv2.line(canvas, (x + 10, y), (x + 30, y), key, 2)
        for k, line in enumerate(lines):
            cv2.putText(canvas, line[:18], (x + 35, y + 4 + 14 * k), _FONT, 0.4, _BLACK, 1)
        y += 4 + 14 * max(len(lines), 1)


def eval_plots(
    dataset: FlightDataset, runs: Sequence[FlightRun], out: Path, samples: int
) -> list[str]:
    """``out/inliers.png`` and ``out/error.png`` (best-candidate inliers and mean inlier error
    against ground truth per frame, one line per run, beside the bar of C3-IT-01 and C3-IT-03;
    a frame with its true tile that raised ringed: C3-IT-01 counts it as 0, not at the count
    drawn; a frame without an error, raised or without ground truth, drawn apart below 0 px;
    frames whose true tile is absent banded grey, as the flight report does) and, for
    ``samples`` frames with the true tile spread over the flight,
    ``out/matches/<strategy>_<frame>.png``; the paths written."""
    charts = zip(
        CHARTS,
        (
            [[float(o.candidate_inliers) for o in r.outcomes] for r in runs],
            [[_finite_or_nan(o.mean_error_px) for o in r.outcomes] for r in runs],
        ),
        (IT01_BAR, IT03_BAR),
        strict=True,
    )
    titles = {"inliers": "best-candidate inliers", "error": "mean inlier error vs ground truth"}
    units = {"inliers": "inliers", "error": "px"}
    bar_names = {
        "inliers": f"IT-01 bar {IT01_BAR.limit:g}",
        "error": f"IT-03 bar {IT03_BAR.limit:g} px",
    }
    counted_apart = {r.strategy: [_counted_apart(o) for o in r.outcomes] for r in runs}
    frames = max((r.outcomes for r in runs), key=len, default=())
    written = [
        str(
            line_chart(
                out / f"{name}.png",
                dict(zip((r.strategy for r in runs), series, strict=True)),
                title=f"{dataset.name}: {titles[name]} per frame",
                ylabel=units[name],
                bar=bar.limit,
                bar_label=bar_names[name],
                marked=counted_apart if name == "inliers" else None,
                marked_note=("raised: counts 0", "in C3-IT-01"),
                frames=[o.index for o in frames],
                shaded=[o.has_truth and not o.true_present for o in frames],
                no_value_label="raised / no value",
            )
        )
        for name, series, bar in charts
    ]
    if samples > 0:
        written += _match_pictures(dataset, runs, out, _sample_frames(dataset, samples))
    return written


def _counted_apart(o: FrameOutcome) -> bool:
    """Whether C3-IT-01 counts the frame at another inlier count than the chart draws: a frame
    with its true tile that raised, drawn at the count it fell short with, counted 0."""
    counted = it01_inliers(o)
    return counted is not None and counted != o.candidate_inliers


def _finite_or_nan(value: float) -> float:
    return value if math.isfinite(value) else math.nan


def _sample_frames(dataset: FlightDataset, samples: int) -> list[FrameRecord]:
    present = [f for f in dataset.frames if f.true_tile_present]
    positions = sorted(
        {round(k * (len(present) - 1) / max(samples - 1, 1)) for k in range(samples)}
    )
    return [present[p] for p in positions] if present else []


def forget_match_pictures(out: Path) -> None:
    """Remove the match pictures an earlier eval drew in ``out`` (``matches/<strategy>_<frame>
    .png``, and the folder once empty): a run draws its own. Nothing else there is touched."""
    folder = out / MATCH_PICTURES
    if not folder.is_dir() or folder.is_symlink():
        return
    for picture in folder.iterdir():
        if re.fullmatch(r".+_\d{4,}\.png", picture.name) and picture.is_file():
            picture.unlink(missing_ok=True)
    with contextlib.suppress(OSError):
        folder.rmdir()  # only when empty


def _match_pictures(
    dataset: FlightDataset, runs: Sequence[FlightRun], out: Path, picks: Sequence[FrameRecord]
) -> list[str]:
    written: list[str] = []
    with dataset.open_store() as store:
        for r in runs:
            by_index = {o.index: o for o in r.outcomes}
            for frame in picks:
                o = by_index.get(frame.index)
                if o is None or o.result is None or o.best_input_index is None:
                    continue
                best = o.result["per_candidate"][0]
                corr = np.asarray(best.get("inlier_correspondences", []), dtype=np.float32)
                cand = frame.candidates[o.best_input_index]
                tile = store.handle(cand.tile_id, dataset.candidate_size_px).decode()
                path = out / MATCH_PICTURES / f"{r.strategy}_{frame.index:04d}.png"
                draw_matches(
                    dataset.nav_frame(frame).image,
                    tile,
                    corr.reshape(-1, 4),
                    path,
                    title=f"{r.strategy} frame {frame.index}: {o.best_inliers} inliers, "
                    f"{'true tile' if o.correct else 'wrong tile'}, err {o.mean_error_px:.2f}px",
                    height=480,
                    calibration=dataset.calibration,  # the inliers are in ORIGINAL px
                )
                written.append(str(path))
    return written
