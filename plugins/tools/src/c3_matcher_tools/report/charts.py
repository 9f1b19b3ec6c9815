"""The flight report's plots as PNG data URIs: the trajectory and the per-frame panels."""

from __future__ import annotations

import base64
import io
import math
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from c3_matcher_tools.dataset.format import FlightDataset
from c3_matcher_tools.report.trajectory import RIGHT_REFUSAL, draw_trajectory
from c3_matcher_tools.run.acceptance import Verdict, verdict
from c3_matcher_tools.run.records import FrameOutcome, FrameStatus

__all__ = [
    "MARKS",
    "MARK_COLOUR",
    "STATUS_COLOUR",
    "WARNING",
    "per_frame_figure",
    "trajectory_figure",
]

MARKS = {
    Verdict.FAILED: "F",
    Verdict.RIGHTLY_RAISED: "R",
    Verdict.WRONG_TILE: "W",
    Verdict.TRUE_TILE_PLACED_WRONG: "W",
    Verdict.OTHER_TILE: "O",
}
"""The letter over a frame in the per-frame chart and the frames table, by :class:`Verdict`
(none over a right pick of the true tile, or one without ground truth)."""
STATUS_COLOUR = {
    FrameStatus.OK: "#2c9f2c",
    FrameStatus.INSUFFICIENT: "#d62728",
    FrameStatus.BACKBONE_ERROR: "#222222",
    FrameStatus.UNREADABLE: "#888888",
}
WARNING = "#f07b12"
"""A wrong fix's colour: a pick, so not a failure's red, yet not a right match's green."""
MARK_COLOUR = {
    Verdict.FAILED: STATUS_COLOUR[FrameStatus.INSUFFICIENT],
    Verdict.RIGHTLY_RAISED: RIGHT_REFUSAL,
    Verdict.WRONG_TILE: WARNING,
    Verdict.TRUE_TILE_PLACED_WRONG: WARNING,
    Verdict.OTHER_TILE: STATUS_COLOUR[FrameStatus.OK],
}
"""Each mark's colour (:data:`MARKS`), by :class:`Verdict`; a wrong fix's bar and a right
refusal's are drawn in theirs too."""


def _plt() -> Any:
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover - the extra is documented
        raise RuntimeError(
            "report.html needs matplotlib: pip install 'c3-matcher-tools[report]'"
        ) from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png_uri(fig: Any) -> str:
    """``fig`` as a PNG data URI. A character its font lacks (a dataset named in CJK) is drawn
    as the font's box, without matplotlib's warning on stderr, where it is no JSON line."""
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", r"Glyph \d+ .* missing from font", UserWarning)
        fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    _plt().close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def trajectory_figure(dataset: FlightDataset, outcomes: Sequence[FrameOutcome], title: str) -> str:
    """The trajectory on the flight's map mosaic (:func:`draw_trajectory`), as a data URI."""
    fig, ax = _plt().subplots(figsize=(8, 8))
    draw_trajectory(ax, dataset, outcomes, title)
    return _png_uri(fig)


def per_frame_figure(outcomes: Sequence[FrameOutcome], min_inliers: int) -> str:
    """The per-frame figure as a data URI: the best inliers against the threshold (always on
    the axis), the errors and the latency, one panel each, frames whose true tile is absent
    banded grey and failed frames, right refusals, wrong fixes and other-tile right fixes
    marked F / R / W / O; legends outside the panels."""
    plt = _plt()
    idx = np.array([o.index for o in outcomes])
    fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    inl = np.array([o.candidate_inliers for o in outcomes])
    _draw_inliers(axes[0], outcomes, idx, inl, min_inliers)
    _draw_errors(axes[1], outcomes, idx)
    _draw_latency(axes[2], outcomes, idx)
    _band_absent_tiles(axes, outcomes)
    _mark_failed_and_wrong(axes[0], outcomes, inl, min_inliers)
    _status_legend(axes[0], outcomes, min_inliers)
    axes[2].xaxis.get_major_locator().set_params(integer=True)
    fig.suptitle("per frame: inliers, error, latency")
    return _png_uri(fig)


def _draw_inliers(
    ax: Any,
    outcomes: Sequence[FrameOutcome],
    idx: NDArray[np.int_],
    inl: NDArray[np.int_],
    min_inliers: int,
) -> None:
    """Each frame's best inlier count, coloured by status (a wrong fix's and a right refusal's
    by :data:`MARK_COLOUR`: a wrong fix matched, yet is no right match), and the threshold."""
    colours = [_bar_colour(o) for o in outcomes]
    ax.bar(idx, inl, color=colours, width=0.8)
    ax.axhline(min_inliers, ls="--", color="#555", lw=1)
    ax.set_ylabel("best inliers")


def _bar_colour(o: FrameOutcome) -> str:
    judged = verdict(o)
    if judged.wrong_fix or judged == Verdict.RIGHTLY_RAISED:
        return MARK_COLOUR[judged]
    return STATUS_COLOUR[o.status]


def _draw_errors(ax: Any, outcomes: Sequence[FrameOutcome], idx: NDArray[np.int_]) -> None:
    """The position errors (vs truth, vs telemetry, the log's GNSS accuracy) in m, the mean
    inlier error in px on a twin axis, frames with GNSS absent or degraded banded yellow; each
    line only where it has a value. Vs telemetry, a frame whose attitude the import assumed
    level is drawn apart: its look point is a level camera's."""
    err_m = np.array([o.position_error_m for o in outcomes], dtype=float)
    err_px = np.array([o.mean_error_px for o in outcomes], dtype=float)
    err_tele = np.array([o.telemetry_error_m for o in outcomes], dtype=float)
    assumed = np.array([o.attitude_assumed for o in outcomes], dtype=bool)
    err_level = np.where(assumed, err_tele, math.nan)
    err_tele = np.where(assumed, math.nan, err_tele)
    accuracy = np.array(
        [math.nan if o.gnss_accuracy_m is None else o.gnss_accuracy_m for o in outcomes],
        dtype=float,
    )
    error_lines = []
    if np.isfinite(err_m).any():
        error_lines += ax.plot(idx, err_m, "o-", color="#ff7f0e", ms=4, label="vs truth")
    if np.isfinite(err_tele).any():
        error_lines += ax.plot(
            idx, err_tele, "^-", color="#2ca02c", ms=4, label="estimate - telemetry"
        )
    if np.isfinite(err_level).any():
        error_lines += ax.plot(
            idx,
            err_level,
            "v--",
            color="#8c564b",
            ms=4,
            label="estimate - a level camera's look point (attitude assumed)",
        )
    if np.isfinite(accuracy).any():
        error_lines += ax.plot(
            idx, accuracy, ":", color="#2ca02c", lw=1.2, label="GNSS accuracy (log)"
        )
    ax.set_ylabel("position error (m)")
    if np.isfinite(err_px).any():
        twin = ax.twinx()
        error_lines += twin.plot(
            idx, err_px, "s:", color="#9467bd", ms=3, label="mean inlier error (px)"
        )
        twin.set_ylabel("inlier error (px)", color="#9467bd")
    for o in outcomes:
        if o.gnss_degraded:
            ax.axvspan(o.index - 0.5, o.index + 0.5, color="#ffbf00", alpha=0.25, lw=0)
    if error_lines:
        ax.legend(
            handles=error_lines,
            loc="upper left",
            bbox_to_anchor=(1.08, 1.0),
            fontsize=8,
            frameon=False,
        )


def _draw_latency(ax: Any, outcomes: Sequence[FrameOutcome], idx: NDArray[np.int_]) -> None:
    """Each frame's time in the matcher."""
    ax.bar(idx, [o.elapsed_ms for o in outcomes], color="#7f7f7f", width=0.8)
    ax.set_ylabel("latency (ms)")
    ax.set_xlabel("frame")


def _band_absent_tiles(axes: Sequence[Any], outcomes: Sequence[FrameOutcome]) -> None:
    """A grey band on every panel over the frames whose true tile is not a candidate."""
    for ax in axes:
        for o in outcomes:
            if o.has_truth and not o.true_present:
                ax.axvspan(o.index - 0.5, o.index + 0.5, color="#bbbbbb", alpha=0.45, lw=0)
        ax.grid(axis="y", alpha=0.3)


def _mark_failed_and_wrong(
    ax: Any, outcomes: Sequence[FrameOutcome], inl: NDArray[np.int_], min_inliers: int
) -> None:
    """Over each frame, above the tallest bar and the threshold (the axis reaches both, so the
    threshold line is drawn even when every bar is below it): its mark (:data:`MARKS`) in its
    colour (:data:`MARK_COLOUR`)."""
    top = max(1.0, float(min_inliers), float(inl.max()) if inl.size else 1.0)
    for o in outcomes:
        judged = verdict(o)
        if mark := MARKS.get(judged):
            colour = MARK_COLOUR[judged]
            ax.text(o.index, top * 1.02, mark, color=colour, ha="center", fontsize=9, weight="bold")
    ax.set_ylim(0, top * 1.12)


def _status_legend(ax: Any, outcomes: Sequence[FrameOutcome], min_inliers: int) -> None:
    """The inlier panel's legend: the statuses, the marks (with what a raised frame's bar over
    the threshold means, when a frame was refused as ambiguous), the bands and the threshold."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [
        Patch(color=STATUS_COLOUR[FrameStatus.OK], label="matched"),
        Patch(color=STATUS_COLOUR[FrameStatus.INSUFFICIENT], label=f"F: {Verdict.FAILED}"),
        Patch(color=RIGHT_REFUSAL, label=f"R: {Verdict.RIGHTLY_RAISED} (true tile absent)"),
        Patch(color=WARNING, label=f"W: {Verdict.WRONG_TILE}, or {Verdict.TRUE_TILE_PLACED_WRONG}"),
        Patch(color="white", label=f"O: {Verdict.OTHER_TILE}"),
        Patch(color="#bbbbbb", label="true tile absent"),
        Line2D([], [], ls="--", color="#555", lw=1, label=f"{min_inliers} inliers threshold"),
    ]
    if any(o.ambiguous is not None for o in outcomes):
        label = "F or R over the threshold: ambiguous (a rival candidate places it elsewhere)"
        handles.append(Patch(color="white", label=label))
    if any(o.gnss_degraded for o in outcomes):
        handles.append(Patch(color="#ffbf00", alpha=0.4, label="GNSS absent or degraded"))
    # outside the axes: a legend never covers a bar or the threshold line
    ax.legend(
        handles=handles, loc="upper left", bbox_to_anchor=(1.08, 1.0), fontsize=8, frameon=False
    )
