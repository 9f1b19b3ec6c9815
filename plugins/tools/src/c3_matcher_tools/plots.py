"""Plots drawn with OpenCV (matplotlib is not a dependency): per-frame line charts, and the
pictures ``eval`` draws of its runs (:func:`eval_plots`)."""

from __future__ import annotations

import contextlib
import math
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

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


def line_chart(
    out: Path,
    series: Mapping[str, Sequence[float]],
    *,
    title: str,
    ylabel: str,
    bar: float | None = None,
    size: tuple[int, int] = (900, 420),
    marked: Mapping[str, Sequence[bool]] | None = None,
    marked_note: Sequence[str] = (),
) -> Path:
    """Write a PNG line chart: one polyline per series over the frame index (x), NaN values
    leave gaps (drawn as an 'x' on the axis); ``bar`` draws a dashed horizontal reference;
    ``marked``: per series, the points ringed with a square, which the legend explains in the
    lines of ``marked_note``."""
    w, h = size
    left, right, top, bottom = 70, 170, 40, 40
    canvas = np.full((h, w, 3), 255, dtype=np.uint8)
    finite = [v for s in series.values() for v in s if math.isfinite(v)]
    if bar is not None:
        finite.append(bar)
    y_max = max(finite) * 1.1 if finite and max(finite) > 0 else 1.0
    n = max((len(s) for s in series.values()), default=1)

    def px(i: float, v: float) -> tuple[int, int]:
        x = left + (w - left - right) * (i / max(n - 1, 1))
        y = h - bottom - (h - top - bottom) * (v / y_max)
        return round(x), round(y)

    cv2.rectangle(canvas, (left, top), (w - right, h - bottom), (0, 0, 0), 1)
    for k in range(5):
        v = y_max * k / 4
        _, y = px(0, v)
        cv2.line(canvas, (left - 4, y), (w - right, y), (225, 225, 225), 1)
        cv2.putText(canvas, f"{v:.3g}", (5, y + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    if bar is not None:
        _, y = px(0, bar)
        for x in range(left, w - right, 12):
            cv2.line(canvas, (x, y), (min(x + 6, w - right), y), (0, 0, 200), 1)
    marks = marked or {}
    for idx, (label, values) in enumerate(series.items()):
        colour = _COLOURS[idx % len(_COLOURS)][::-1]
        _polyline(canvas, values, colour, px, marks.get(label, ()))
        _legend_entry(canvas, (w - right, top + 18 * idx + 10), label, colour)
    if any(any(m) for m in marks.values()):
        _legend_entry(canvas, (w - right, top + 18 * len(series) + 10), "", None, marked_note)
    cv2.putText(canvas, title, (left, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1)
    axis = f"{ylabel} / frame index"
    cv2.putText(canvas, axis, (left, h - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    return write_png(canvas[:, :, ::-1], out)


def _polyline(
    canvas: NDArray[np.uint8],
    values: Sequence[float],
    colour: tuple[int, int, int],
    px: Callable[[float, float], tuple[int, int]],
    marked: Sequence[bool] = (),
) -> None:
    """One series: a line through its finite values, an 'x' on the axis for each NaN, a
    square around each ``marked`` point."""
    previous = None
    for i, v in enumerate(values):
        if not math.isfinite(v):
            x, y = px(i, 0)
            cv2.drawMarker(canvas, (x, y), colour, cv2.MARKER_TILTED_CROSS, 7, 1)
            previous = None
            continue
        p = px(i, v)
        if previous is not None:
            cv2.line(canvas, previous, p, colour, 2, cv2.LINE_AA)
        cv2.circle(canvas, p, 2, colour, -1)
        if i < len(marked) and marked[i]:
            cv2.drawMarker(canvas, p, colour, cv2.MARKER_SQUARE, 11, 1)
        previous = p


def _legend_entry(
    canvas: NDArray[np.uint8],
    at: tuple[int, int],
    label: str,
    colour: tuple[int, int, int] | None,
    note: Sequence[str] = (),
) -> None:
    """A legend entry right of the plot (whose right edge and row ``at`` gives): a series'
    line in ``colour`` and its ``label``, or (``colour`` None) the square that rings marked
    points and the lines of ``note``."""
    x, y = at
    font, black = cv2.FONT_HERSHEY_SIMPLEX, (0, 0, 0)
    if colour is None:
        cv2.drawMarker(canvas, (x + 20, y), black, cv2.MARKER_SQUARE, 11, 1)
    else:
        cv2.line(canvas, (x + 10, y), (x + 30, y), colour, 2)
    for k, line in enumerate(note or (label,)):
        cv2.putText(canvas, line[:18], (x + 35, y + 4 + 14 * k), font, 0.4, black, 1)


def eval_plots(
    dataset: FlightDataset, runs: Sequence[FlightRun], out: Path, samples: int
) -> list[str]:
    """``out/inliers.png`` and ``out/error.png`` (best-candidate inliers and mean inlier error
    against ground truth per frame, one line per run; a frame with its true tile that raised
    ringed: C3-IT-01 counts it as 0, not at the count drawn) and, for ``samples`` frames with
    the true tile spread over the flight, ``out/matches/<strategy>_<frame>.png``; the paths
    written."""
    charts = zip(
        CHARTS,
        (
            [[float(o.candidate_inliers) for o in r.outcomes] for r in runs],
            [[_finite_or_nan(o.mean_error_px) for o in r.outcomes] for r in runs],
        ),
        (IT01_BAR.limit, IT03_BAR.limit),
        strict=True,
    )
    titles = {"inliers": "best-candidate inliers", "error": "mean inlier error vs ground truth"}
    counted_apart = {r.strategy: [_counted_apart(o) for o in r.outcomes] for r in runs}
    written = [
        str(
            line_chart(
                out / f"{name}.png",
                dict(zip((r.strategy for r in runs), series, strict=True)),
                title=f"{dataset.name}: {titles[name]} per frame",
                ylabel={"inliers": "inliers", "error": "px"}[name],
                bar=bar,
                marked=counted_apart if name == "inliers" else None,
                marked_note=("raised: counts 0", "in C3-IT-01"),
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
                )
                written.append(str(path))
    return written
