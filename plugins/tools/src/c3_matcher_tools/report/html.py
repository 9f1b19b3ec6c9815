# ruff: noqa: E501  (HTML templates and plot calls read better unwrapped)
"""A self-contained HTML flight report: one file, every image embedded as a data URI, no script,
no network. Plots are drawn with matplotlib (the tools' ``report`` extra).

Sections: summary figures (the frames judged as eval judges them: wrong fixes, failures, right
refusals where the true tile is absent); the trajectory on the map mosaic of the flight's tile
store (truth vs estimate, error segments, failed frames and right refusals marked; for a
recorded flight the telemetry's track, frames whose GNSS was absent or degraded marked); inliers, error (m and px; a recorded flight's
estimate minus the telemetry's look point beside the GNSS accuracy the log states, or a level
camera's look point where the log has no attitude) and latency per
frame with absent-tile, wrong-tile, other-tile right fixes, failed frames and right refusals marked (legends outside the plots); a gallery of the worst and best
frames (:func:`c3_matcher.viz.render_match`); the run's settings and provenance. This module
assembles the page; the plots are drawn in :mod:`.charts`, the gallery's pictures in
:mod:`.pictures`.
"""

from __future__ import annotations

import html
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from c3_matcher.atomic import write_text_atomically
from c3_matcher_tools.dataset.format import FlightDataset
from c3_matcher_tools.report.charts import MARKS, per_frame_figure, trajectory_figure
from c3_matcher_tools.report.pictures import gallery_pictures
from c3_matcher_tools.run.acceptance import WRONG_FIX_PX, Verdict, verdict
from c3_matcher_tools.run.records import FrameOutcome, FrameStatus
from c3_matcher_tools.run.scoring import (
    RunSummary,
    attitude_noise_words,
    dropped_lines,
    figure,
    summarize,
)

__all__ = ["write_report"]


def _verdict(o: FrameOutcome) -> str:
    """The frame's :class:`Verdict` in the frames table, after the chart's mark (F, R, W,
    O); for a frame refused as ambiguous, the rival candidate that made it so."""
    judged = verdict(o)
    mark = MARKS.get(judged)
    absent = " (true tile absent)" if o.has_truth and not o.true_present else ""
    rival = "" if o.ambiguous is None else f"; ambiguous: {o.ambiguous}"
    return (f"{mark} {judged}" if mark else str(judged)) + absent + rival


def _gnss_cell(o: FrameOutcome) -> str:
    if o.gnss_degraded is None:
        return "-"
    acc = "?" if o.gnss_accuracy_m is None else f"{o.gnss_accuracy_m:.1f}"
    return ("degraded " if o.gnss_degraded else "ok ") + f"({acc})"


def _table(rows: Sequence[tuple[str, Any]]) -> str:
    cells = "".join(
        f"<tr><th>{html.escape(str(k))}</th><td>{html.escape('-' if v is None else str(v))}</td></tr>"
        for k, v in rows
    )
    return f"<table>{cells}</table>"


def _setting(key: str, value: Any, keypoint_budget: Any) -> str:
    """A setting in the product's words: on / off for a switch; a setting left unset "unset
    (strategy default)" (the strategy's own value applies; ``max_keypoints``'s is the
    ``keypoint_budget`` the run kept); a table of options as JSON, "none" when empty."""
    if value is None:
        budget = keypoint_budget if key == "max_keypoints" else None
        return "unset (strategy default" + ("" if budget is None else f": {budget}") + ")"
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, dict | list):
        return json.dumps(value) if value else "none"
    return str(value)


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
    """Write ``out`` (report.html) for one replayed run; returns its path. ``summary``: the
    run's report, shown as it is; the headline figures are the ``outcomes``' own."""
    figures = summarize(outcomes)
    kpis = _kpis(figures, outcomes, dataset.store_path)
    min_inliers = int(settings.get("min_inliers_threshold", 60))
    reference = "truth" if figures.with_truth else "telemetry"
    traj = trajectory_figure(
        dataset, outcomes, f"{dataset.name}: {reference} vs estimate ({strategy})"
    )
    per_frame = per_frame_figure(outcomes, min_inliers)
    pictures = gallery_pictures(dataset, outcomes, gallery)
    budget = summary.get("keypoint_budget")
    page = _Page(
        dataset.name,
        strategy,
        kpis,
        traj,
        per_frame,
        pictures,
        _frame_rows(outcomes),
        provenance,
        {k: _setting(k, v, budget) for k, v in settings.items()},
        summary,
        attitude_noise_words(dataset.meta.get("attitude_noise")),
    )
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    return write_text_atomically(out, page.html())


def _telemetry_kpis(summary: RunSummary) -> list[tuple[str, Any]]:
    """The telemetry's figures for a flight that has telemetry: the estimate minus the look
    point over the frames whose attitude was measured; apart, the frames whose attitude was
    assumed level and the estimate minus a level camera's look point."""
    if not summary.with_telemetry:
        return []
    assumed = summary.attitude_assumed_frames
    kpis: list[tuple[str, Any]] = [
        (
            "estimate - telemetry p50 / p95 (m)"
            + (", frames with a measured attitude" if assumed else ""),
            f"{figure(summary.telemetry_error_m_p50)} / {figure(summary.telemetry_error_m_p95)}",
        )
    ]
    if assumed:
        kpis.append(
            (
                f"attitude assumed level on {len(assumed)} frame(s) (the log has no attitude "
                "at their time): not counted; estimate - a level camera's look point p50 (m)",
                figure(summary.telemetry_error_m_p50_attitude_assumed),
            )
        )
    return kpis


def _judged_kpis(summary: RunSummary, outcomes: Sequence[FrameOutcome]) -> list[tuple[str, Any]]:
    """The frames as judged (:class:`Verdict`): with ground truth, the wrong fixes among those
    scored (eval's false-confident); the failed frames; where a true tile is absent, those
    failed apart from those that rightly raised (the right answer there, C3-IT-05) of the
    frames without their true tile."""
    judged = [(o, verdict(o)) for o in outcomes]
    kpis: list[tuple[str, Any]] = []
    if summary.with_truth:
        wrong = f"{summary.false_confident}/{summary.scored}"
        kpis.append(("wrong fixes (false-confident)", wrong))
    failed = [o for o, v in judged if v == Verdict.FAILED]
    if not summary.true_absent:
        return [*kpis, ("failed", len(failed))]
    present = [o for o in failed if o.true_present or not o.has_truth]
    return [
        *kpis,
        ("failed (true tile present)", len(present)),
        *(
            [("failed (true tile absent)", len(failed) - len(present))]
            if len(present) < len(failed)
            else []
        ),
        ("rightly raised (true tile absent)", f"{summary.absent_raised}/{summary.true_absent}"),
    ]


def _ambiguous_kpis(summary: RunSummary) -> list[tuple[str, Any]]:
    """How many frames were refused as ambiguous, when any was: their inliers may pass the
    threshold, yet they got no fix."""
    if not summary.ambiguous:
        return []
    return [("ambiguous (no fix: a rival candidate places the frame elsewhere)", summary.ambiguous)]


def _kpis(
    summary: RunSummary, outcomes: Sequence[FrameOutcome], store: Path
) -> list[tuple[str, Any]]:
    """The headline figures (label, value) of the run's ``summary`` and ``outcomes`` (each
    judged, :func:`_judged_kpis`); the telemetry's only for a flight that has telemetry; the
    candidates dropped, by cause, when any was (and the tile ``store`` named when most were
    dropped for their tiles); the frames refused as ambiguous, when any was."""
    return [
        ("frames", summary.frames),
        ("matched", summary.count(FrameStatus.OK)),
        *_ambiguous_kpis(summary),
        *_judged_kpis(summary, outcomes),
        (
            "correct tile",
            f"{summary.correct_candidate}/{summary.true_present}"
            if summary.with_truth
            else "no truth",
        ),
        (
            "position error p50 / p95 (m), every matched frame",
            f"{figure(summary.position_error_m_p50)} / {figure(summary.position_error_m_p95)}"
            f" ({summary.position_error_frames} frames)",
        ),
        *_telemetry_kpis(summary),
        (
            "frame ms p50 / p95",
            f"{figure(summary.frame_ms_p50, '.0f')} / {figure(summary.frame_ms_p95, '.0f')}",
        ),
        *(("candidates", line) for line in dropped_lines(summary, store)),
    ]


def _frame_rows(outcomes: Sequence[FrameOutcome]) -> str:
    """The frames table's rows, one per frame, escaped."""
    return "".join(
        "<tr>"
        + "".join(
            f"<td>{html.escape(str(c))}</td>"
            for c in (
                o.index,
                o.status_words,
                o.candidate_inliers,
                _verdict(o),
                figure(o.position_error_m),
                figure(o.telemetry_error_m) + (" (level assumed)" if o.attitude_assumed else ""),
                _gnss_cell(o),
                figure(o.mean_error_px, ".2f"),
                figure(o.elapsed_ms, ".0f"),
                "" if o.est_lat is None else f"{o.est_lat:.6f}, {o.est_lon:.6f}",
            )
        )
        + "</tr>"
        for o in outcomes
    )


@dataclass(frozen=True)
class _Page:
    """What the report shows, each section ready to place: the flight, the strategy, the
    headline figures, the two plots and the gallery as data URIs, the frames table's rows, the
    run's settings (in words), provenance and summary, and the noise put on the attitudes (its
    words, :func:`attitude_noise_words`; empty without)."""

    name: str
    strategy: str
    kpis: list[tuple[str, Any]]
    trajectory: str
    per_frame: str
    pictures: list[tuple[str, str]]
    rows: str
    provenance: dict[str, Any]
    settings: dict[str, str]
    summary: dict[str, Any]
    noise: str = ""

    @property
    def settings_heading(self) -> str:
        """The settings table's heading: ``[lightglue]`` among it only where the strategy reads
        those settings (the run's report leaves them out otherwise)."""
        lightglue = any(k.startswith("lightglue.") for k in self.settings)
        return "[matcher] and [lightglue] settings" if lightglue else "[matcher] settings"

    def html(self) -> str:
        """The whole page: one file, no script."""
        return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>c3-matcher flight report: {html.escape(self.name)}</title>
<style>{CSS}</style></head><body>
<h1>Flight report: {html.escape(self.name)} with {html.escape(self.strategy + self.noise)}</h1>
<div class="kpi">{"".join(f"<div>{html.escape(str(k))}<b>{html.escape(str(v))}</b></div>" for k, v in self.kpis)}</div>
<h2>Trajectory</h2>
<p>Frame centres on the tile store's imagery: truth (blue; a recorded flight: where its telemetry
says the frame looks, green) and estimate (orange); red segments join each frame's reference and
estimated centre; x: a failed frame, cyan ring: a frame that {Verdict.RIGHTLY_RAISED} with its
true tile absent (R below), diamond: a wrong fix (W below), square: another tile that places the
frame right, yellow ring: GNSS absent or degraded.</p>
<img id="trajectory" alt="trajectory" src="{self.trajectory}">
<h2>Per frame</h2>
<p>Grey bands: frames whose true tile is not among the candidates (they should raise); yellow
bands: GNSS absent or degraded. F: {Verdict.FAILED} (no fix where a match was due: fewer inliers
than the threshold, ambiguous, or an error); R: {Verdict.RIGHTLY_RAISED} (no fix, too few inliers
or ambiguous, with the true tile absent: the right answer, C3-IT-05; cyan bar). Ambiguous, its
status in the table: a rival candidate with at least half the best's inliers places the frame
elsewhere, so no fix is given whatever the inliers (its bar may pass the threshold); W: a wrong fix, one eval counts
false-confident (orange bar: {Verdict.WRONG_TILE}, or
{Verdict.TRUE_TILE_PLACED_WRONG}: inliers over {WRONG_FIX_PX:g} px from the ground truth, or
their error unknown);
O: {Verdict.OTHER_TILE} (a candidate other than the true tile whose inliers place the frame
within {WRONG_FIX_PX:g} px: eval's "other tile"). A recorded flight's error is the estimate
minus the telemetry's position, beside the accuracy its GNSS states; on a frame whose attitude
the log lacks (attitude assumed level, "level assumed" in the table) it is the distance from
where a level camera would look, not counted in the figures above.</p>
<img id="per-frame" alt="per-frame plots" src="{self.per_frame}">
<h2>Worst and best frames</h2>
<p>Worst: frames that went wrong (no match where the true tile was a candidate, a wrong tile, or
the true tile with its inliers more than {WRONG_FIX_PX:g} px off the ground truth, or by an
unknown error); best: right
matches and frames that rightly raised with their true tile absent; without ground truth, matched
frames by inlier count.{"" if any(c.startswith("worst") for c, _ in self.pictures) else " No frame went wrong."}
Left: the query rectified onto the best tile; right: the tile with the query's footprint
(yellow); green lines agree with the ground truth (or the fitted homography without truth) within
3 px, red do not; the strip shows every candidate with its inlier count.</p>
<div class="gallery">{"".join(f'<figure><img class="frame" alt="{html.escape(c)}" src="{u}"><figcaption>{html.escape(c)}</figcaption></figure>' for c, u in self.pictures)}</div>
<h2>Frames</h2>
<table><tr><th>frame</th><th>status</th><th>inliers</th><th>result</th><th>error vs truth m</th><th>estimate - telemetry m</th><th>GNSS (accuracy m)</th><th>error px</th><th>ms</th><th>estimate lat, lon</th></tr>{self.rows}</table>
<h2>Settings and provenance</h2>
{_table([("strategy replayed", self.strategy), *self.provenance.items()])}
<h3>{self.settings_heading}</h3>
{_table(list(self.settings.items()))}
<h3>summary</h3>
<pre>{html.escape(json.dumps(self.summary, indent=1, default=str))}</pre>
</body></html>
"""
