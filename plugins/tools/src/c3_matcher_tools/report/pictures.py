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
from c3_matcher_tools.run.acceptance import Verdict, inliers_within_bound, verdict
from c3_matcher_tools.run.records import FrameOutcome, FrameStatus

__all__ = ["frame_picture", "gallery_frames", "gallery_pictures"]


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
    """The :func:`c3_matcher.viz.render_match` picture of one replayed frame: a matched frame
    on its best tile through the result's ``best_homography``, whether or not its inlier
    correspondences were kept (``replay --no-correspondences`` drops them: the footprint is
    drawn, no lines)."""
    frame = next(f for f in dataset.frames if f.index == outcome.index)
    query = dataset.nav_frame(frame).image
    size = dataset.candidate_size_px
    counts, corr = _inliers(outcome)
    views = _candidate_views(frame, outcome, store, size, counts)
    hom = _best_homography(outcome)
    best = outcome.best_input_index if outcome.status == FrameStatus.OK else None
    errors = None
    if hom is not None and best is not None and corr is not None and len(corr):
        h_true = frame.candidates[best].h_tile_to_undistorted
        if h_true is not None:
            errors = inlier_errors_px(h_true, dataset.calibration, corr.astype(np.float32))
    return render_match(
        query,
        views,
        best_index=best,
        h_query_to_tile=hom,
        correspondences=corr,
        calibration=dataset.calibration,
        errors_px=errors,
        title=_picture_title(outcome),
        panel=panel,
    )


def _best_homography(outcome: FrameOutcome) -> NDArray[np.float64] | None:
    """The result's ``best_homography``: the map its position comes from (replay writes it
    whenever one fits, :func:`c3_matcher.georef.best_query_to_tile`, with or without the
    inlier correspondences); None when the frame did not match or none fits."""
    if outcome.status != FrameStatus.OK or outcome.result is None:
        return None
    stored = outcome.result.get("best_homography")
    return None if stored is None else np.asarray(stored, dtype=np.float64).reshape(3, 3)


def _inliers(outcome: FrameOutcome) -> tuple[dict[int, int], NDArray[np.float64] | None]:
    """Each candidate's inlier count by input position, and the best candidate's inlier
    correspondences (N, 4; none when the result was written without them); empty / None when
    the frame has no result."""
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
    """The picture's title: inliers, verdict and error of a matched frame; the verdict of one
    that did not match (failed, or rightly raised) and why."""
    if outcome.status == FrameStatus.OK:
        pos = (
            ""
            if not math.isfinite(outcome.position_error_m)
            else f", {outcome.position_error_m:.1f} m off"
        )
        judged = "" if not outcome.has_truth else f" {verdict(outcome)}"
        return f"frame {outcome.index}: {outcome.best_inliers} inliers,{judged}{pos}"
    title = f"frame {outcome.index}: {verdict(outcome)} ({outcome.status_words}, best {outcome.insufficient_best} inliers)"  # noqa: E501
    if outcome.has_truth and not outcome.true_present:
        title += ", true tile absent"
    return title


def gallery_pictures(
    dataset: FlightDataset, outcomes: Sequence[FrameOutcome], n: int
) -> list[tuple[str, str]]:
    """(caption, data URI) of the ``n`` worst and ``n`` best frames whose image could be read
    (an ``unreadable`` frame has no picture: the table names it and why), as
    :func:`gallery_frames` picks them."""
    worst, best = gallery_frames(outcomes, n)
    out: list[tuple[str, str]] = []
    with dataset.open_store() as store:
        for label, group in (("worst", worst), ("best", best)):
            for o in group:
                out.append(
                    (f"{label}: frame {o.index}", _jpeg_uri(frame_picture(dataset, o, store)))
                )
    return out


def gallery_frames(
    outcomes: Sequence[FrameOutcome], n: int
) -> tuple[list[FrameOutcome], list[FrameOutcome]]:
    """The gallery's (worst, best) frames, at most ``n`` each, no frame in both, unreadable
    frames left out. Worst: frames that went wrong (:func:`_went_wrong`), worst first; best:
    frames that went right (:func:`_went_right`), best first. A matched frame without ground
    truth to judge it by can be either: such frames fill the room either group has left, the
    fewest inliers towards worst and the most towards best. A flight with frames of both kinds
    shows both groups."""
    readable = [o for o in outcomes if o.status != FrameStatus.UNREADABLE]
    worst = sorted((o for o in readable if _went_wrong(o)), key=_wrongness, reverse=True)[:n]
    best = sorted((o for o in readable if _went_right(o)), key=_rightness)[:n]
    unjudged = sorted(
        (o for o in readable if not _went_wrong(o) and not _went_right(o)),
        key=lambda o: (o.best_inliers, -_finite(o.telemetry_error_m, 0.0)),
    )  # worst first
    while unjudged and (len(worst) < n or len(best) < n):
        if len(worst) < n:
            worst.append(unjudged.pop(0))
        if unjudged and len(best) < n:
            best.append(unjudged.pop())
    return worst, best


def _finite(value: float, otherwise: float) -> float:
    return value if math.isfinite(value) else otherwise


def _right_match(o: FrameOutcome) -> bool:
    """Matched the true tile, its inliers within the evaluation's wrong-fix bound
    (:func:`inliers_within_bound`); an unknown inlier error (no truth homography) leaves the
    verdict to the tile, where the evaluation's false-confidence measure counts it wrong."""
    if o.status != FrameStatus.OK or not o.has_truth or not o.correct:
        return False
    return inliers_within_bound(o) is not False


def _rightly_raised(o: FrameOutcome) -> bool:
    """Raised InsufficientInliersError on a frame whose true tile is not among its candidates:
    what it should do (:attr:`Verdict.RIGHTLY_RAISED`)."""
    return verdict(o) == Verdict.RIGHTLY_RAISED


def _went_right(o: FrameOutcome) -> bool:
    return _right_match(o) or _rightly_raised(o)


def _went_wrong(o: FrameOutcome) -> bool:
    """Failed where a match was due (or the matcher failed), or matched a frame with ground
    truth anywhere but right; a matched frame without ground truth is neither."""
    if o.status == FrameStatus.OK:
        return o.has_truth and not _right_match(o)
    return not _rightly_raised(o)


def _wrongness(o: FrameOutcome) -> tuple[float, float]:
    """Higher is worse: a missed match (fewest inliers worst), then a wrong fix (most
    inliers, the most confidently wrong, worst)."""
    if o.status != FrameStatus.OK:
        return (2.0, -o.insufficient_best)
    return (1.0, o.best_inliers)


def _rightness(o: FrameOutcome) -> tuple[float, float, float, float]:
    """Lower is better: right matches by inlier error (px), position error (m) and inliers,
    then frames that rightly raised (fewest inliers first)."""
    if o.status != FrameStatus.OK:
        return (1.0, o.insufficient_best, 0.0, 0.0)
    return (
        0.0,
        _finite(o.mean_error_px, math.inf),
        _finite(o.position_error_m, math.inf),
        -o.best_inliers,
    )
