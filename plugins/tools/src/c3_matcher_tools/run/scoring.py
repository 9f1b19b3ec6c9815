"""Scoring a run against a flight's ground truth and telemetry: the per-frame fingerprint
(C3-IT-02), where the frame truly looks, the best candidate's inlier error (ORIGINAL frame px)
and the summary of a run (counts, timing in ms, position errors in m)."""

from __future__ import annotations

import hashlib
import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from c3_matcher import camera as cam
from c3_matcher.dto import MatchResult
from c3_matcher_tools.dataset.format import FlightDataset, FrameRecord
from c3_matcher_tools.dataset.sources.options import number_ranges
from c3_matcher_tools.dataset.truth import inlier_errors_px
from c3_matcher_tools.geodesy import axis_ground_point
from c3_matcher_tools.run.acceptance import Verdict, verdict
from c3_matcher_tools.run.records import FrameOutcome, FrameStatus

__all__ = [
    "RunSummary",
    "TelemetryReference",
    "attitude_noise_words",
    "best_candidate_error",
    "damaged_store_line",
    "dropped_lines",
    "figure",
    "result_fingerprint",
    "status_line",
    "summarize",
    "telemetry_lines",
    "telemetry_reference",
    "truth_position",
]


def figure(value: float | None, spec: str | None = None) -> str:
    """A figure as reports print it: "n/a" for None, NaN and infinity; ``spec`` when given,
    else three significant digits to the millimetre (0.0309 -> "0.031", 12.34 -> "12.3", 9.996 ->
    "10.0": the digits counted after rounding), so a centimetre error never reads as 0."""
    if value is None or not math.isfinite(value):
        return "n/a"
    if spec is not None:
        return format(value, spec)
    text = f"{value:.{_decimals(value)}f}"
    rounded = float(text)  # rounding may carry it to the next power of ten: 9.996 -> 10.00
    return f"{value:.{_decimals(rounded)}f}" if rounded else text


def _decimals(value: float) -> int:
    """The decimals that show ``value`` to three significant digits, at most three."""
    digits = 2 - math.floor(math.log10(abs(value))) if value else 1
    return min(max(digits, 0), 3)


def result_fingerprint(
    result: MatchResult | None, insufficient_best: int = 0, ambiguous: str | None = None
) -> str:
    """Bit-for-bit digest of ``per_candidate`` (tile ids, counts, residual float bits,
    correspondence bytes), ``best_candidate_idx`` and the input order; for an
    InsufficientInliersError, of its best inlier count, and for an AmbiguousMatchError of its
    rival too (``ambiguous``, in the error's words: a run whose rival changed differs)."""
    h = hashlib.blake2b(digest_size=16)
    if result is None:
        h.update(f"insufficient:{insufficient_best}".encode())
        if ambiguous is not None:
            h.update(f"ambiguous:{ambiguous}".encode())
        return h.hexdigest()
    h.update(str(result.best_candidate_idx).encode())
    h.update(repr(result.diagnostics.get("input_index")).encode())
    for c in result.per_candidate:
        h.update(repr((c.tile_id.as_list(), c.inlier_count, c.ransac_outlier_count)).encode())
        h.update(np.float64(c.per_candidate_residual_px).tobytes())
        h.update(c.inlier_correspondences.tobytes())
    return h.hexdigest()


def attitude_noise_words(noise: object) -> str:
    """What a run's first line (replay's, eval's, the flight report's) says of the noise
    ``--attitude-noise-deg`` put on the flight's attitudes (``noise``: the dataset's
    ``attitude_noise``, as ``report.json`` holds it): ", attitude noise 2 deg (1 sigma)";
    nothing for a flight without noise."""
    sigma = noise.get("sigma_deg") if isinstance(noise, dict) else None
    if not isinstance(sigma, int | float) or not sigma:
        return ""
    return f", attitude noise {sigma:g} deg (1 sigma)"


def truth_position(dataset: FlightDataset, frame: FrameRecord) -> tuple[float, float] | None:
    """(lat, lon) where the frame's principal point truly looks: through a candidate's
    ground-truth homography (the true one first; a distractor's maps the same ground plane, so a
    frame without its true tile has its truth too), else where the optical axis meets flat
    ground from the record's ``pose`` nadir, attitude and height (``axis_ground_point``: the
    pose's footprint centre, the mean of the footprint's corners, is another point, tens of
    metres off at 20 deg of tilt); None without truth."""
    from c3_matcher.georef import tile_px_to_lonlat

    k = dataset.calibration.K
    for cand in sorted(frame.candidates, key=lambda c: not c.is_true):
        if cand.h_tile_to_undistorted is not None:
            size = dataset.candidate_size_px
            g, centre = np.linalg.inv(cand.h_tile_to_undistorted), np.array([k[0, 2], k[1, 2], 1])
            if abs(g[2] @ centre) <= 1e-9 * np.linalg.norm(g[2]) * np.linalg.norm(centre):
                continue  # the frame's centre looks along the ground plane: it meets no ground
            tile_px = cam.apply_homography(g, [centre[:2]])
            lon, lat = tile_px_to_lonlat(cand.tile_id, (size, size), tile_px)[0]
            return float(lat), float(lon)
    pose = frame.pose
    if frame.has_truth and "nadir_lat" in pose and "nadir_lon" in pose:
        nadir = float(pose["nadir_lat"]), float(pose["nadir_lon"])
        return axis_ground_point(*nadir, frame.height_m, frame.attitude, dataset.calibration)
    return None


@dataclass(frozen=True)
class TelemetryReference:
    """Where the flight's recorded position, attitude and height put a frame's centre (the
    import's look point, lat/lon), the GNSS accuracy the log states, whether GNSS was absent
    or degraded (None: the log does not say) and whether the attitude was assumed level (the
    log had none at the frame: the look point is a level camera's, not the frame's)."""

    lat: float
    lon: float
    gnss_accuracy_m: float | None
    gnss_degraded: bool | None
    attitude_assumed: bool = False


def telemetry_reference(frame: FrameRecord) -> TelemetryReference | None:
    """The frame's :class:`TelemetryReference`; None without telemetry."""
    t = frame.telemetry
    if "look_lat" not in t or "look_lon" not in t:
        return None
    accuracy = t.get("gnss_accuracy_m")
    flags = t.get("flags")
    return TelemetryReference(
        float(t["look_lat"]),
        float(t["look_lon"]),
        None if accuracy is None else float(accuracy),
        None if "gnss_degraded" not in t else bool(t["gnss_degraded"]),
        isinstance(flags, list) and "attitude_assumed" in flags,
    )


def best_candidate_error(
    dataset: FlightDataset, frame: FrameRecord, result: MatchResult
) -> tuple[int, float]:
    """(input index of the best candidate, mean error of its inliers against that candidate's
    ground-truth homography in ORIGINAL frame px; NaN without truth or inliers)."""
    best_input = int(result.diagnostics["input_index"][0])
    cand = frame.candidates[best_input]
    if cand.h_tile_to_undistorted is None:
        return best_input, math.nan
    errors = inlier_errors_px(
        cand.h_tile_to_undistorted,
        dataset.calibration,
        result.per_candidate[0].inlier_correspondences,
    )
    return best_input, float(np.mean(errors)) if errors.size else math.nan


def _percentile(values: list[float], q: float) -> float | None:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.percentile(np.asarray(finite), q)) if finite else None


@dataclass(frozen=True)
class RunSummary:
    """Counts and timing of a run (:func:`summarize`). Percentiles are None without a value:
    position errors (m) against ground truth over every matched frame that has one
    (``position_error_frames`` of them, true tile a candidate or not: C3-IT-03's position
    figures count only those whose true tile is); for a recorded flight, the estimate minus
    the telemetry's look point (m) over the located frames whose attitude was measured
    (``telemetry_error_frames`` of them) and those of them whose GNSS was good, the stated GNSS
    accuracy, the frames whose GNSS was absent or degraded, and apart the frames whose attitude
    the import assumed level (``attitude_assumed_frames``: their look point is a level
    camera's, hundreds of metres from a tilted one's) with the p50 of their estimate minus it.
    ``true_present`` and ``correct_candidate`` count the frames with ground truth whose image
    was read (``FrameOutcome.scored``, as C3-IT-04 does), ``true_absent`` and
    ``absent_raised`` those whose true tile is not a candidate, raised with their tiles read
    (as C3-IT-05 counts the right answer: a damaged store's frame is none); frame
    times are those of the frames the matcher ran on (an unreadable image never reached it).
    ``candidates``: those the matcher was given over the run; ``candidates_dropped``: those it
    dropped, counted by cause (:class:`DroppedCandidate`), most first; ``tile_dropped``: those
    dropped for their tiles (a tile failing its sha256 or not decoding: the store's fault);
    ``false_confident_frames``: the frames whose pick places them wrong, as eval counts them
    false-confident (:func:`~c3_matcher_tools.run.acceptance.verdict`), of the :attr:`scored`
    ones; ``ambiguous_frames``: those of the ``insufficient`` ones refused as ambiguous (a rival
    candidate placed the frame elsewhere, ``FrameOutcome.ambiguous``), whatever their inliers."""

    frames: int
    by_status: Mapping[FrameStatus, int]
    with_truth: int
    true_present: int
    correct_candidate: int
    true_absent: int
    absent_raised: int
    georeferenced: int
    position_error_m_p50: float | None
    position_error_m_p95: float | None
    position_error_frames: int
    with_telemetry: int
    telemetry_error_m_p50: float | None
    telemetry_error_m_p95: float | None
    telemetry_error_m_p50_gnss_good: float | None
    telemetry_error_frames: int
    gnss_accuracy_m_p50: float | None
    gnss_degraded_frames: tuple[int, ...]
    attitude_assumed_frames: tuple[int, ...]
    telemetry_error_m_p50_attitude_assumed: float | None
    frame_ms_p50: float | None
    frame_ms_p95: float | None
    frame_ms_mean: float | None
    total_s: float
    candidates: int = 0
    candidates_dropped: tuple[tuple[str, int], ...] = ()
    tile_dropped: int = 0
    false_confident_frames: tuple[int, ...] = ()
    ambiguous_frames: tuple[int, ...] = ()

    def count(self, status: FrameStatus) -> int:
        return self.by_status.get(status, 0)

    @property
    def failed(self) -> int:
        """Frames that did not match, whatever the reason."""
        return self.frames - self.count(FrameStatus.OK)

    @property
    def scored(self) -> int:
        """The frames with ground truth whose image was read: those judged against truth."""
        return self.true_present + self.true_absent

    @property
    def false_confident(self) -> int:
        """The frames whose pick places them wrong (``false_confident_frames``)."""
        return len(self.false_confident_frames)

    @property
    def ambiguous(self) -> int:
        """The frames refused as ambiguous (``ambiguous_frames``), counted as ``insufficient``."""
        return len(self.ambiguous_frames)

    def to_json(self) -> dict[str, Any]:
        """Its form in ``report.json`` and ``eval.json``: the counts by status flattened, as
        ``"ok"``, ``"insufficient"``, ... after ``"frames"`` (``"insufficient"`` counts the
        ``"ambiguous"`` frames too: both raised ``InsufficientInliersError``)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        by_status = out.pop("by_status")
        return {
            "frames": out.pop("frames"),
            **{str(s): by_status.get(s, 0) for s in FrameStatus},
            **out,
            "gnss_degraded_frames": list(self.gnss_degraded_frames),
            "attitude_assumed_frames": list(self.attitude_assumed_frames),
            "candidates_dropped": dict(self.candidates_dropped),
            "false_confident": self.false_confident,
            "false_confident_frames": list(self.false_confident_frames),
            "ambiguous": self.ambiguous,
            "ambiguous_frames": list(self.ambiguous_frames),
        }

    @property
    def dropped_for_tiles(self) -> bool:
        """Most of the candidates the matcher was given were dropped for their tiles: the
        tile store, not the matcher or the flight, is what failed."""
        return self.tile_dropped * 2 > self.candidates


def summarize(outcomes: Sequence[FrameOutcome]) -> RunSummary:
    """The :class:`RunSummary` of a run's ``outcomes``."""
    matched = [o.elapsed_ms for o in outcomes if o.status != FrameStatus.UNREADABLE]
    present = [o for o in outcomes if o.scored and o.true_present]
    absent = [o for o in outcomes if o.scored and not o.true_present]
    pos = [o.position_error_m for o in outcomes if o.status == FrameStatus.OK]
    pos = [p for p in pos if math.isfinite(p)]
    tele = [o for o in outcomes if o.telemetry_lat is not None]
    tele_ok = [o for o in tele if o.status == FrameStatus.OK]
    measured = [o.telemetry_error_m for o in tele_ok if not o.attitude_assumed]
    level = [o.telemetry_error_m for o in tele_ok if o.attitude_assumed]
    good = [
        o.telemetry_error_m for o in tele_ok if not o.attitude_assumed and o.gnss_degraded is False
    ]
    accuracy = [o.gnss_accuracy_m for o in tele if o.gnss_accuracy_m is not None]
    causes = Counter(d.cause for o in outcomes for d in o.dropped)
    return RunSummary(
        frames=len(outcomes),
        by_status=MappingProxyType({s: sum(o.status == s for o in outcomes) for s in FrameStatus}),
        with_truth=sum(o.has_truth for o in outcomes),
        true_present=len(present),
        correct_candidate=sum(o.correct for o in present),
        true_absent=len(absent),
        absent_raised=sum(verdict(o) == Verdict.RIGHTLY_RAISED for o in absent),
        georeferenced=sum(o.est_lat is not None for o in outcomes),
        position_error_m_p50=_percentile(pos, 50),
        position_error_m_p95=_percentile(pos, 95),
        position_error_frames=len(pos),
        with_telemetry=len(tele),
        telemetry_error_m_p50=_percentile(measured, 50),
        telemetry_error_m_p95=_percentile(measured, 95),
        telemetry_error_m_p50_gnss_good=_percentile(good, 50),
        telemetry_error_frames=sum(math.isfinite(e) for e in measured),
        gnss_accuracy_m_p50=_percentile(accuracy, 50),
        gnss_degraded_frames=tuple(o.index for o in tele if o.gnss_degraded),
        attitude_assumed_frames=tuple(o.index for o in tele if o.attitude_assumed),
        telemetry_error_m_p50_attitude_assumed=_percentile(level, 50),
        frame_ms_p50=_percentile(matched, 50),
        frame_ms_p95=_percentile(matched, 95),
        frame_ms_mean=float(np.mean(matched)) if matched else None,
        total_s=float(np.sum(matched)) / 1e3,
        candidates=sum(o.candidates for o in outcomes),
        candidates_dropped=tuple(causes.most_common()),
        tile_dropped=sum(d.of_tile for o in outcomes for d in o.dropped),
        false_confident_frames=tuple(o.index for o in outcomes if verdict(o).wrong_fix),
        ambiguous_frames=tuple(o.index for o in outcomes if o.ambiguous is not None),
    )


def status_line(s: RunSummary) -> str:
    """How ``replay`` and ``eval`` say the frames ended: matched, too few inliers, refused as
    ambiguous (when any: their inliers may pass the threshold), backbone errors, and unreadable
    images (when any)."""
    unreadable = s.count(FrameStatus.UNREADABLE)
    return (
        f"ok {s.count(FrameStatus.OK)}, insufficient inliers "
        f"{s.count(FrameStatus.INSUFFICIENT) - s.ambiguous}"
        + (
            f", ambiguous {s.ambiguous} (a rival candidate places the frame elsewhere: no fix)"
            if s.ambiguous
            else ""
        )
        + f", backbone errors {s.count(FrameStatus.BACKBONE_ERROR)}"
        + (f", unreadable images {unreadable}" if unreadable else "")
    )


def dropped_lines(s: RunSummary, store: Path | str) -> list[str]:
    """What ``replay`` and ``eval`` say of the candidates the matcher dropped (nothing when
    none was): how many, by cause; then, when most were dropped for their tiles, that the
    tile store ``store`` is what failed, and what to do."""
    if not s.candidates_dropped:
        return []
    total = sum(n for _, n in s.candidates_dropped)
    lines = [
        f"candidates dropped {total} of {s.candidates}: "
        + ", ".join(f"{cause} {n}" for cause, n in s.candidates_dropped)
    ]
    damaged = damaged_store_line(s, store)
    return lines if damaged is None else [*lines, damaged]


def damaged_store_line(s: RunSummary, store: Path | str) -> str | None:
    """The line that says the tile store ``store`` is damaged, and what to do, when most of
    the candidates were dropped for their tiles (:attr:`RunSummary.dropped_for_tiles`); None
    otherwise."""
    if not s.dropped_for_tiles:
        return None
    return (
        f"{s.tile_dropped} of {s.candidates} candidates were dropped for their tiles: the "
        f"tile store {store} is damaged (tiles failing their sha256 or not decoding, each "
        "named in matcher.log): restore it or build it again (`c3-matcher tiles build`)"
    )


def telemetry_lines(s: RunSummary) -> list[str]:
    """What ``replay`` and ``eval`` say of a recorded flight's figures: the estimate minus the
    telemetry's look point over the frames whose attitude was measured, beside the GNSS accuracy
    the log states; then, apart, the frames whose attitude the import assumed level and how far
    the estimates lie from where a level camera would look."""
    degraded, assumed = s.gnss_degraded_frames, s.attitude_assumed_frames
    accuracy = s.gnss_accuracy_m_p50
    lines = [
        f"estimate - telemetry look point m p50 {figure(s.telemetry_error_m_p50)}, "
        f"p95 {figure(s.telemetry_error_m_p95)} over {s.telemetry_error_frames} located "
        f"frame(s){' with a measured attitude' if assumed else ''} ("
        + ("GNSS accuracy not stated" if accuracy is None else f"GNSS accuracy {accuracy:.1f} m")
        + f"; GNSS absent or degraded on {len(degraded)} frame(s)"
        + (f": {number_ranges(degraded)})" if degraded else ")")
    ]
    if assumed:
        lines.append(
            f"attitude assumed level on {len(assumed)} frame(s) ({number_ranges(assumed)}; the "
            "log has no attitude at their time): not counted above; estimate - a level "
            f"camera's look point m p50 {figure(s.telemetry_error_m_p50_attitude_assumed)}"
        )
    return lines
