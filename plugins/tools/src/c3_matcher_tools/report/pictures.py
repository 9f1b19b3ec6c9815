"""The flight report's per-frame pictures: one replayed frame's match, the worst and best frames."""

from __future__ import annotations

import base64
import math
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from c3_matcher.viz import CandidateView, render_match
from c3_matcher_tools.dataset.format import FlightDataset, FrameRecord
from c3_matcher_tools.dataset.truth import inlier_errors_px
from c3_matcher_tools.report.charts import FAILED, WRONG
from c3_matcher_tools.run.records import FrameOutcome, FrameStatus

__all__ = ["frame_picture", "gallery_pictures"]


def _jpeg_uri(rgb: NDArray[np.uint8], quality: int = 85) -> str:
    ok, enc = cv2.imencode(
        ".jpg", np.ascontiguousarray(rgb[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, quality]
    )
    if not ok:
        raise OSError("cannot encode a JPEG")
    return "data:image/jpeg;base64," + base64.b64encode(enc.tobytes()).decode()


def frame_picture(
    dataset: FlightDataset, outcome: FrameOutcome, store: Any, panel: int = 360
) -> NDArray[np.uint8]:
    """The :func:`c3_matcher.viz.render_match` picture of one replayed frame."""
    frame = next(f for f in dataset.frames if f.index == outcome.index)
    query = dataset.nav_frame(frame).image
    size = dataset.candidate_size_px
    counts, corr = _inliers(outcome)
    views = _candidate_views(frame, outcome, store, size, counts)
    hom = _best_homography(outcome, corr)
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


def _best_homography(
    outcome: FrameOutcome, corr: NDArray[np.float64] | None
) -> NDArray[np.float64] | None:
    """The result's ``best_homography``: the map its position comes from (replay writes it
    whenever one fits, :func:`c3_matcher.georef.best_query_to_tile`); None without inliers."""
    if outcome.result is None or corr is None or not len(corr):
        return None
    stored = outcome.result.get("best_homography")
    return None if stored is None else np.asarray(stored, dtype=np.float64).reshape(3, 3)


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
    if outcome.status == FrameStatus.OK:
        pos = (
            ""
            if not math.isfinite(outcome.position_error_m)
            else f", {outcome.position_error_m:.1f} m off"
        )
        verdict = (
            "" if not outcome.has_truth else (" true tile" if outcome.correct else f" {WRONG}")
        )
        return f"frame {outcome.index}: {outcome.best_inliers} inliers,{verdict}{pos}"
    title = f"frame {outcome.index}: {FAILED} ({outcome.status}, best {outcome.insufficient_best} inliers)"  # noqa: E501
    if outcome.has_truth and not outcome.true_present:
        title += ", true tile absent"
    return title


def gallery_pictures(
    dataset: FlightDataset, outcomes: Sequence[FrameOutcome], n: int
) -> list[tuple[str, str]]:
    """(caption, data URI) of the ``n`` worst and ``n`` best frames whose image could be read
    (an ``unreadable`` frame has no picture: the table names it and why)."""

    def badness(o: FrameOutcome) -> tuple[float, float]:
        if o.status != FrameStatus.OK:
            return (
                3.0 if (o.has_truth and o.true_present) or not o.has_truth else 0.5,
                -o.insufficient_best,
            )
        if o.has_truth and not o.correct:
            return (2.0, 0.0)
        err = o.position_error_m if math.isfinite(o.position_error_m) else 0.0
        return (1.0, err - o.best_inliers / 1e4)

    readable = [o for o in outcomes if o.status != FrameStatus.UNREADABLE]
    ranked = sorted(readable, key=badness, reverse=True)
    worst = ranked[:n]
    best = [o for o in reversed(ranked) if o.status == FrameStatus.OK and o not in worst][:n]
    out: list[tuple[str, str]] = []
    with dataset.open_store() as store:
        for label, group in (("worst", worst), ("best", best)):
            for o in group:
                out.append(
                    (f"{label}: frame {o.index}", _jpeg_uri(frame_picture(dataset, o, store)))
                )
    return out
