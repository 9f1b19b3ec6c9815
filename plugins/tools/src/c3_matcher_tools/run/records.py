"""The run records: what one frame (:class:`FrameOutcome`, with the candidates the matcher
dropped, :class:`DroppedCandidate`) and one strategy over one flight (:class:`FlightRun`) came
to. Frozen values; ``to_json`` gives their JSON forms."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np

from c3_matcher import __version__
from c3_matcher.stages.candidate_features import TILE_DECODE_PHASE

__all__ = [
    "DroppedCandidate",
    "FlightRun",
    "FrameOutcome",
    "FrameStatus",
]


class FrameStatus(StrEnum):
    """How a frame of a run ended: its ``status`` in ``results.jsonl`` and the reports."""

    OK = "ok"
    """Matched: the result's best candidate reached the inlier threshold."""
    INSUFFICIENT = "insufficient"
    """No fix (``InsufficientInliersError``): no candidate reached the threshold, or, the
    frame's ``ambiguous`` set (``AmbiguousMatchError``), a rival candidate with at least half the
    best's inliers placed the frame elsewhere."""
    BACKBONE_ERROR = "backbone_error"
    """The matcher's backbone failed on the frame (``MatcherBackboneError``)."""
    UNREADABLE = "unreadable"
    """The frame's image could not be read or decoded: the matcher never saw it."""


@dataclass(frozen=True)
class DroppedCandidate:
    """A candidate the matcher dropped on a frame: its input position, its tile id, why (in the
    words of ``c3-matcher match``'s ``dropped``) and ``cause``, what the run's summary counts
    it under: ``"<step> <error type>"`` for a backbone error (``"tile_decode TileDigestError"``:
    the tile failed its sha256), ``"no inliers"`` or ``"refused on geometry"``."""

    candidate_index: int
    tile_id: Any
    reason: str
    cause: str

    @property
    def of_tile(self) -> bool:
        """Dropped for its tile: it could not be read, checked or decoded from the store."""
        return self.cause.split(" ", 1)[0] == TILE_DECODE_PHASE


@dataclass(frozen=True)
class FrameOutcome:
    """One frame's outcome. ``best_input_index``: input position of the best candidate;
    ``correct``: the best is the true tile; ``mean_error_px``: mean inlier error of the best
    candidate against ground truth (ORIGINAL frame px), NaN when not matched; ``fingerprint``:
    blake2b of the per-frame result content (C3-IT-02), excluding ``matched_at``.
    ``telemetry_lat``/``telemetry_lon``: where the flight's own telemetry (GNSS position,
    attitude, height) says the frame's centre looks; ``telemetry_error_m``: the estimate's
    distance from it (m, NaN when either is missing); ``gnss_accuracy_m``: the horizontal
    accuracy the log states for that fix; ``gnss_degraded``: GNSS was absent or degraded at the
    frame (None: no telemetry, or it does not say); ``attitude_assumed``: the log had no
    attitude at the frame, so the import assumed it level and the look point is where a level
    camera would look, not the frame's (summaries keep such frames apart); ``candidates``: how
    many the matcher was given, ``dropped``: those it dropped and why; ``ambiguous``: the frame
    got no fix because two candidates place it in different places (``AmbiguousMatchError``),
    that rival in its words (None otherwise; its status is still ``insufficient``, its
    ``insufficient_best`` the best's inliers, which may pass the threshold). ``result``: the result
    as JSON (:func:`c3_matcher.serialize.result_to_json`, each kept candidate placed on the map by
    :func:`c3_matcher.georef.candidate_placement`), its inlier correspondences held as the
    result's float32 (I, 4) arrays until :meth:`to_json` writes them as lists.
    ``captured_at_ns``: the frame's capture time as its dataset records it (ns from the flight's
    first frame), the ``captured_at_ns`` of the FDR's records of the frame (None: not known)."""

    index: int
    frame_id: str
    status: FrameStatus
    elapsed_ms: float
    true_present: bool
    best_inliers: int
    best_input_index: int | None
    correct: bool
    mean_error_px: float
    residual_px: float
    fingerprint: str
    error: str | None
    result: dict[str, Any] | None
    has_truth: bool = True
    est_lat: float | None = None
    est_lon: float | None = None
    truth_lat: float | None = None
    truth_lon: float | None = None
    position_error_m: float = math.nan
    insufficient_best: int = 0
    telemetry_lat: float | None = None
    telemetry_lon: float | None = None
    telemetry_error_m: float = math.nan
    gnss_accuracy_m: float | None = None
    gnss_degraded: bool | None = None
    attitude_assumed: bool = False
    candidates: int = 0
    dropped: tuple[DroppedCandidate, ...] = ()
    ambiguous: str | None = None
    captured_at_ns: int | None = None

    @property
    def status_words(self) -> str:
        """The status as the tables and reports show it: ``ambiguous`` for a frame refused as
        ambiguous (its best candidate may have passed the threshold), else the status."""
        return "ambiguous" if self.ambiguous is not None else str(self.status)

    @property
    def scored(self) -> bool:
        """Whether accuracy measures count this frame: it has ground truth and its image was
        read (an unreadable image is the camera's loss, not the matcher's)."""
        return self.has_truth and self.status != FrameStatus.UNREADABLE

    @property
    def no_tile_read(self) -> bool:
        """Every candidate the matcher was given was dropped for its tile (the store could not
        give it): the frame's outcome says nothing of the matcher, only of the tile store."""
        return self.candidates > 0 and sum(d.of_tile for d in self.dropped) >= self.candidates

    @property
    def candidate_inliers(self) -> int:
        """The best candidate's inlier count, whether the frame matched or raised (the count
        below the threshold, or, ambiguous, the best's whatever the threshold); ``best_inliers``
        is the matched result's, 0 when it raised."""
        return self.best_inliers if self.status == FrameStatus.OK else self.insufficient_best

    def to_json(self) -> dict[str, Any]:
        """Its line in ``results.jsonl``; ``ambiguous`` only on a frame refused as ambiguous,
        so that the other frames' keys are those they always had."""
        out = asdict(self)
        if out["ambiguous"] is None:
            del out["ambiguous"]
        for key in ("mean_error_px", "residual_px", "position_error_m", "telemetry_error_m"):
            if not math.isfinite(out[key]):
                out[key] = None
        for candidate in (out["result"] or {}).get("per_candidate", ()):
            corr = candidate.get("inlier_correspondences")
            if isinstance(corr, np.ndarray):
                candidate["inlier_correspondences"] = corr.tolist()
        return out


@dataclass(frozen=True)
class FlightRun:
    """One strategy flown over one flight: its frames' outcomes in order, the matcher settings
    it ran with (``[matcher]`` resolved for that strategy: its own defaults where the
    configuration leaves a setting unset, as JSON), start-up and wall time (s), the
    ``[lightglue]`` settings resolved for it the same way (its pair matcher's, when it uses
    LightGlue), ``planned``, the frames it was to fly when it was stopped before the last
    (None: it flew them all), the log lines its ``matcher.log`` could not take, ``backend``:
    its feature backend's provenance (execution provider and engines, as its FDR records
    them; empty for a matcher without one) and ``keypoint_budget``: the keypoints per image
    that backend kept (None: it declares no budget)."""

    strategy: str
    settings: dict[str, Any]
    outcomes: tuple[FrameOutcome, ...]
    startup_s: float
    wall_s: float
    lightglue: dict[str, Any] = field(default_factory=dict)
    planned: int | None = None
    log_lines_lost: int = 0
    backend: dict[str, Any] = field(default_factory=dict)
    keypoint_budget: int | None = None

    @property
    def complete(self) -> bool:
        """Whether every frame the run was to fly has its outcome."""
        return self.planned is None or len(self.outcomes) >= self.planned

    @property
    def progress(self) -> dict[str, Any]:
        """What says, beside its results, whether the run is whole: ``complete``,
        ``frames_done`` and ``frames_planned`` (those it was to fly)."""
        done = len(self.outcomes)
        planned = done if self.planned is None else self.planned
        return {"complete": self.complete, "frames_done": done, "frames_planned": planned}

    @property
    def matcher_labels(self) -> list[str]:
        """The results' ``matcher_label`` values, sorted (one for a strategy)."""
        return sorted({str(o.result["matcher_label"]) for o in self.outcomes if o.result})

    @property
    def provenance(self) -> dict[str, Any]:
        """What the run ran on, as ``report.html``, ``report.json`` and ``eval.json`` name it:
        the c3-matcher version, the results' matcher labels, and the backend's execution
        provider and engines (``backend``)."""
        return {"c3-matcher": __version__, "matcher_labels": self.matcher_labels, **self.backend}
