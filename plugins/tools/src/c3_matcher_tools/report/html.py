# ruff: noqa: E501  (HTML templates and plot calls read better unwrapped)
"""A self-contained HTML flight report: one file, every image embedded as a data URI, no script,
no network. Plots are drawn with matplotlib (the tools' ``report`` extra).

Sections: summary figures; the trajectory on the map mosaic of the flight's tile store (truth
vs estimate, error segments, failed frames marked; for a recorded flight the telemetry's track,
frames whose GNSS was absent or degraded marked); inliers, error (m and px; a recorded flight's
estimate minus the telemetry's look point beside the GNSS accuracy the log states) and latency per
frame with absent-tile, wrong-tile and failed frames marked (legends outside the plots); a gallery of the worst and best
frames (:func:`c3_matcher.viz.render_match`); the run's settings and provenance.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.atomic import write_text_atomically
from c3_matcher.georef import fit_query_to_tile
from c3_matcher.viz import CandidateView, render_match
from c3_matcher_tools.dataset.format import FlightDataset, FrameRecord
from c3_matcher_tools.dataset.truth import inlier_errors_px
from c3_matcher_tools.report.trajectory import draw_trajectory
from c3_matcher_tools.run.records import FrameOutcome

__all__ = ["frame_picture", "write_report"]

FAILED = "failed"
WRONG = "wrong tile"
"""The words the chart's legend and the frames table both use (the chart marks F / W)."""
STATUS_COLOUR = {"ok": "#2c9f2c", "insufficient": "#d62728", "backbone_error": "#222222"}


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
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    _plt().close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _jpeg_uri(rgb: NDArray[np.uint8], quality: int = 85) -> str:
    ok, enc = cv2.imencode(
        ".jpg", np.ascontiguousarray(rgb[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, quality]
    )
    if not ok:
        raise OSError("cannot encode a JPEG")
    return "data:image/jpeg;base64," + base64.b64encode(enc.tobytes()).decode()


def _trajectory(dataset: FlightDataset, outcomes: Sequence[FrameOutcome], title: str) -> str:
    fig, ax = _plt().subplots(figsize=(8, 8))
    draw_trajectory(ax, dataset, outcomes, title)
    return _png_uri(fig)


def _per_frame(outcomes: Sequence[FrameOutcome], min_inliers: int) -> str:
    """The per-frame figure: the best inliers against the threshold, the errors and the latency,
    one panel each, frames whose true tile is absent banded grey and failed or wrong-tile frames
    marked F / W; legends outside the panels."""
    plt = _plt()
    idx = np.array([o.index for o in outcomes])
    fig, axes = plt.subplots(3, 1, figsize=(11, 8), sharex=True)
    inl = np.array([o.candidate_inliers for o in outcomes])
    _draw_inliers(axes[0], outcomes, idx, inl, min_inliers)
    _draw_errors(axes[1], outcomes, idx)
    _draw_latency(axes[2], outcomes, idx)
    _band_absent_tiles(axes, outcomes)
    _mark_failed_and_wrong(axes[0], outcomes, inl)
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
    """Each frame's best inlier count, coloured by status, and the threshold."""
    colours = [STATUS_COLOUR.get(o.status, "#888") for o in outcomes]
    ax.bar(idx, inl, color=colours, width=0.8)
    ax.axhline(min_inliers, ls="--", color="#555", lw=1)
    ax.set_ylabel("best inliers")


def _draw_errors(ax: Any, outcomes: Sequence[FrameOutcome], idx: NDArray[np.int_]) -> None:
    """The position errors (vs truth, vs telemetry, the log's GNSS accuracy) in m, the mean
    inlier error in px on a twin axis, frames with GNSS absent or degraded banded yellow; each
    line only where it has a value."""
    err_m = np.array([o.position_error_m for o in outcomes], dtype=float)
    err_px = np.array([o.mean_error_px for o in outcomes], dtype=float)
    err_tele = np.array([o.telemetry_error_m for o in outcomes], dtype=float)
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
    ax: Any, outcomes: Sequence[FrameOutcome], inl: NDArray[np.int_]
) -> None:
    """W over a frame that matched a wrong tile, F over a failed one, above the tallest bar."""
    top = max(1.0, float(inl.max()) if inl.size else 1.0)
    for o in outcomes:
        if o.status == "ok" and o.has_truth and o.true_present and not o.correct:
            ax.text(
                o.index, top * 1.02, "W", color="#d62728", ha="center", fontsize=9, weight="bold"
            )
        elif o.status != "ok":
            ax.text(
                o.index, top * 1.02, "F", color="#d62728", ha="center", fontsize=9, weight="bold"
            )
    ax.set_ylim(0, top * 1.12)


def _status_legend(ax: Any, outcomes: Sequence[FrameOutcome], min_inliers: int) -> None:
    """The inlier panel's legend: the statuses, the marks, the bands and the threshold."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [
        Patch(color=STATUS_COLOUR["ok"], label="matched"),
        Patch(color=STATUS_COLOUR["insufficient"], label=f"F: {FAILED}"),
        Patch(color="white", label=f"W: {WRONG}"),
        Patch(color="#bbbbbb", label="true tile absent"),
        Line2D([], [], ls="--", color="#555", lw=1, label=f"{min_inliers} inliers threshold"),
    ]
    if any(o.gnss_degraded for o in outcomes):
        handles.append(Patch(color="#ffbf00", alpha=0.4, label="GNSS absent or degraded"))
    # outside the axes: a legend never covers a bar or the threshold line
    ax.legend(
        handles=handles, loc="upper left", bbox_to_anchor=(1.08, 1.0), fontsize=8, frameon=False
    )


def frame_picture(
    dataset: FlightDataset, outcome: FrameOutcome, store: Any, panel: int = 360
) -> NDArray[np.uint8]:
    """The :func:`c3_matcher.viz.render_match` picture of one replayed frame."""
    frame = next(f for f in dataset.frames if f.index == outcome.index)
    query = dataset.nav_frame(frame).image
    size = dataset.candidate_size_px
    counts, corr = _inliers(outcome)
    views = _candidate_views(frame, outcome, store, size, counts)
    hom = fit_query_to_tile(corr, dataset.calibration) if corr is not None and len(corr) else None
    errors = None
    if hom is not None and outcome.best_input_index is not None and corr is not None:
        h_true = frame.candidates[outcome.best_input_index].h_tile_to_undistorted
        if h_true is not None:
            errors = inlier_errors_px(h_true, dataset.calibration, corr.astype(np.float32))
    return render_match(
        query,
        views,
        best_index=outcome.best_input_index if hom is not None else None,
        h_query_to_tile=hom,
        correspondences=corr,
        calibration=dataset.calibration,
        errors_px=errors,
        title=_picture_title(outcome),
        panel=panel,
    )


def _inliers(outcome: FrameOutcome) -> tuple[dict[int, int], NDArray[np.float64] | None]:
    """Each candidate's inlier count by input position, and the best candidate's inlier
    correspondences (N, 4); both empty / None when the frame has no result."""
    counts: dict[int, int] = {}
    if outcome.result is None:
        return counts, None
    for c in outcome.result["per_candidate"]:
        counts[int(c["tile_index"])] = int(c["inlier_count"])
    corr = np.asarray(
        outcome.result["per_candidate"][0].get("inlier_correspondences", []), np.float64
    ).reshape(-1, 4)
    return counts, corr


def _candidate_views(
    frame: FrameRecord, outcome: FrameOutcome, store: Any, size: int, counts: dict[int, int]
) -> list[CandidateView]:
    """The picture's strip: every candidate tile from ``store`` (grey when it cannot be read)
    with its position, inlier count, and whether it is the best and the true one."""
    views = []
    for i, cand in enumerate(frame.candidates):
        try:
            image = store.handle(cand.tile_id, size).decode()
        except Exception:
            image = np.full((size, size, 3), 60, np.uint8)
        views.append(
            CandidateView(
                image,
                f"{cand.tile_id.lat:.4f},{cand.tile_id.lon:.4f}",
                counts.get(i),
                i == outcome.best_input_index,
                cand.is_true,
            )
        )
    return views


def _picture_title(outcome: FrameOutcome) -> str:
    """The picture's title: inliers, verdict and error of a matched frame; why a frame
    failed."""
    if outcome.status == "ok":
        pos = (
            ""
            if not math.isfinite(outcome.position_error_m)
            else f", {outcome.position_error_m:.1f} m off"
        )
        verdict = (
            "" if not outcome.has_truth else (" true tile" if outcome.correct else f" {WRONG}")
        )
        return f"frame {outcome.index}: {outcome.best_inliers} inliers,{verdict}{pos}"
    title = f"frame {outcome.index}: {FAILED} ({outcome.status}, best {outcome.insufficient_best} inliers)"
    if outcome.has_truth and not outcome.true_present:
        title += ", true tile absent"
    return title


def _gallery(
    dataset: FlightDataset, outcomes: Sequence[FrameOutcome], n: int
) -> list[tuple[str, str]]:
    """(caption, data URI) of the ``n`` worst and ``n`` best frames."""

    def badness(o: FrameOutcome) -> tuple[float, float]:
        if o.status != "ok":
            return (
                3.0 if (o.has_truth and o.true_present) or not o.has_truth else 0.5,
                -o.insufficient_best,
            )
        if o.has_truth and not o.correct:
            return (2.0, 0.0)
        err = o.position_error_m if math.isfinite(o.position_error_m) else 0.0
        return (1.0, err - o.best_inliers / 1e4)

    ranked = sorted(outcomes, key=badness, reverse=True)
    worst = ranked[:n]
    best = [o for o in reversed(ranked) if o.status == "ok" and o not in worst][:n]
    out: list[tuple[str, str]] = []
    with dataset.open_store() as store:
        for label, group in (("worst", worst), ("best", best)):
            for o in group:
                out.append(
                    (f"{label}: frame {o.index}", _jpeg_uri(frame_picture(dataset, o, store)))
                )
    return out


def _verdict(o: FrameOutcome) -> str:
    """The frame's result in the chart's words: F failed, W wrong tile."""
    if o.status != "ok":
        return f"F {FAILED}" + (" (true tile absent)" if o.has_truth and not o.true_present else "")
    if not o.has_truth:
        return "matched"
    if not o.true_present:
        return "matched (true tile absent)"
    return "true tile" if o.correct else f"W {WRONG}"


def _gnss_cell(o: FrameOutcome) -> str:
    if o.gnss_degraded is None:
        return "-"
    acc = "?" if o.gnss_accuracy_m is None else f"{o.gnss_accuracy_m:.1f}"
    return ("degraded " if o.gnss_degraded else "ok ") + f"({acc})"


def _table(rows: Sequence[tuple[str, Any]]) -> str:
    cells = "".join(
        f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(str(v))}</td></tr>" for k, v in rows
    )
    return f"<table>{cells}</table>"


CSS = """
body{font-family:system-ui,sans-serif;margin:24px;color:#222;max-width:1200px}
h1{font-size:22px}h2{font-size:18px;margin-top:28px;border-bottom:1px solid #ccc}
table{border-collapse:collapse;font-size:13px}th,td{border:1px solid #ddd;padding:3px 8px;text-align:left}
th{background:#f4f4f4}img{max-width:100%;border:1px solid #ddd}
.figs{display:flex;gap:16px;flex-wrap:wrap}.gallery figure{margin:0 0 16px 0}
.kpi{display:flex;gap:12px;flex-wrap:wrap}.kpi div{background:#f4f6fa;padding:8px 14px;border-radius:6px}
.kpi b{display:block;font-size:20px}
"""


def write_report(
    out: Path,
    dataset: FlightDataset,
    outcomes: Sequence[FrameOutcome],
    *,
    strategy: str,
    summary: dict[str, Any],
    settings: dict[str, Any],
    provenance: dict[str, Any],
    gallery: int = 3,
) -> Path:
    """Write ``out`` (report.html) for one replayed run; returns its path."""
    kpis = _kpis(summary)
    min_inliers = int(settings.get("min_inliers_threshold", 60))
    reference = "truth" if summary.get("with_truth") else "telemetry"
    traj = _trajectory(dataset, outcomes, f"{dataset.name}: {reference} vs estimate ({strategy})")
    per_frame = _per_frame(outcomes, min_inliers)
    pictures = _gallery(dataset, outcomes, gallery)
    page = _Page(
        dataset.name,
        strategy,
        kpis,
        traj,
        per_frame,
        pictures,
        _frame_rows(outcomes),
        provenance,
        settings,
        summary,
    )
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    return write_text_atomically(out, page.html())


def _fmt(v: Any, spec: str = ".1f") -> str:
    """``v`` formatted with ``spec``; "n/a" for None, NaN and infinity."""
    return (
        "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)
    )


def _kpis(summary: dict[str, Any]) -> list[tuple[str, Any]]:
    """The headline figures (label, value) of the run's ``summary``; the telemetry's error only
    for a flight that has telemetry."""
    tele_kpi = (
        "estimate - telemetry p50 / p95 (m)",
        f"{_fmt(summary.get('telemetry_error_m_p50'))} / {_fmt(summary.get('telemetry_error_m_p95'))}",
    )
    return [
        ("frames", summary.get("frames")),
        ("matched", summary.get("ok")),
        ("failed", (summary.get("insufficient") or 0) + (summary.get("backbone_error") or 0)),
        (
            "correct tile",
            f"{summary.get('correct_candidate')}/{summary.get('true_present')}"
            if summary.get("with_truth")
            else "no truth",
        ),
        (
            "position error p50 / p95 (m)",
            f"{_fmt(summary.get('position_error_m_p50'))} / {_fmt(summary.get('position_error_m_p95'))}",
        ),
        *([tele_kpi] if summary.get("with_telemetry") else []),
        (
            "frame ms p50 / p95",
            f"{_fmt(summary.get('frame_ms_p50'), '.0f')} / {_fmt(summary.get('frame_ms_p95'), '.0f')}",
        ),
    ]


def _frame_rows(outcomes: Sequence[FrameOutcome]) -> str:
    """The frames table's rows, one per frame, escaped."""
    return "".join(
        "<tr>"
        + "".join(
            f"<td>{html.escape(str(c))}</td>"
            for c in (
                o.index,
                o.status,
                o.candidate_inliers,
                _verdict(o),
                _fmt(o.position_error_m),
                _fmt(o.telemetry_error_m),
                _gnss_cell(o),
                _fmt(o.mean_error_px, ".2f"),
                _fmt(o.elapsed_ms, ".0f"),
                "" if o.est_lat is None else f"{o.est_lat:.6f}, {o.est_lon:.6f}",
            )
        )
        + "</tr>"
        for o in outcomes
    )


@dataclass(frozen=True)
class _Page:
    """What the report shows, each section ready to place: the headline figures, the two plots
    and the gallery as data URIs, the frames table's rows, and the run's settings, provenance
    and summary."""

    name: str
    strategy: str
    kpis: list[tuple[str, Any]]
    trajectory: str
    per_frame: str
    pictures: list[tuple[str, str]]
    rows: str
    provenance: dict[str, Any]
    settings: dict[str, Any]
    summary: dict[str, Any]

    def html(self) -> str:
        """The whole page: one file, no script."""
        return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>c3-matcher flight report: {html.escape(self.name)}</title>
<style>{CSS}</style></head><body>
<h1>Flight report: {html.escape(self.name)} with {html.escape(self.strategy)}</h1>
<div class="kpi">{"".join(f"<div>{html.escape(str(k))}<b>{html.escape(str(v))}</b></div>" for k, v in self.kpis)}</div>
<h2>Trajectory</h2>
<p>Frame centres on the tile store's imagery: truth (blue; a recorded flight: where its telemetry
says the frame looks, green) and estimate (orange); red segments join each frame's reference and
estimated centre; x: a failed frame, diamond: a wrong tile, yellow ring: GNSS absent or
degraded.</p>
<img id="trajectory" alt="trajectory" src="{self.trajectory}">
<h2>Per frame</h2>
<p>Grey bands: frames whose true tile is not among the candidates (they should fail); yellow
bands: GNSS absent or degraded. F: {FAILED} (fewer inliers than the threshold, or an error);
W: {WRONG} chosen. A recorded flight's error is the estimate minus the telemetry's position,
beside the accuracy its GNSS states.</p>
<img id="per-frame" alt="per-frame plots" src="{self.per_frame}">
<h2>Worst and best frames</h2>
<p>Left: the query rectified onto the best tile; right: the tile with the query's footprint
(yellow); green lines agree with the ground truth (or the fitted homography without truth) within
3 px, red do not; the strip shows every candidate with its inlier count.</p>
<div class="gallery">{"".join(f'<figure><img class="frame" alt="{html.escape(c)}" src="{u}"><figcaption>{html.escape(c)}</figcaption></figure>' for c, u in self.pictures)}</div>
<h2>Frames</h2>
<table><tr><th>frame</th><th>status</th><th>inliers</th><th>result</th><th>error vs truth m</th><th>estimate - telemetry m</th><th>GNSS (accuracy m)</th><th>error px</th><th>ms</th><th>estimate lat, lon</th></tr>{self.rows}</table>
<h2>Settings and provenance</h2>
{_table([("strategy replayed", self.strategy), *self.provenance.items()])}
<h3>[matcher] settings</h3>
{_table(list(self.settings.items()))}
<h3>summary</h3>
<pre>{html.escape(json.dumps(self.summary, indent=1, default=str))}</pre>
</body></html>
"""
