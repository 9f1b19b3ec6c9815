"""Flying a flight: every frame (or some) of a ``c3-flight/1`` dataset through a matcher, each
scored against the flight's ground truth and telemetry (:func:`run_flight`), and one strategy
opened, flown and timed (:func:`fly`)."""

from __future__ import annotations

import contextlib
import math
import signal
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from c3_matcher.compose import strategy_settings
from c3_matcher.config import C3Settings
from c3_matcher.dto import MatchResult
from c3_matcher.errors import (
    AmbiguousMatchError,
    InsufficientInliersError,
    InvalidInputError,
    MatcherBackboneError,
)
from c3_matcher.georef import haversine_m
from c3_matcher.logs import MATCHER_GEOMETRY_REFUSED, MATCHER_ZERO_INLIERS
from c3_matcher.plugins.manager import PluginHost
from c3_matcher.protocols import CrossDomainMatcher
from c3_matcher.serialize import CALIBRATION_SIZE_FIX, result_to_json
from c3_matcher.stages.drops import HeardDrop, drops_heard
from c3_matcher.tiles import DECODABLE_FORMATS, MmapTileHandle, image_file_size
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher.unread_settings import strategy_reads_lightglue
from c3_matcher_tools.dataset.format import FlightDataset, FrameRecord
from c3_matcher_tools.run.matcher import (
    NO_OVERRIDES,
    Overrides,
    PreparedMatcher,
    prepare_matcher,
)
from c3_matcher_tools.run.records import DroppedCandidate, FlightRun, FrameOutcome, FrameStatus
from c3_matcher_tools.run.results_file import (
    RESULTS_FILE,
    KeepFrame,
    appending_results,
    partial_results,
)
from c3_matcher_tools.run.scoring import (
    TelemetryReference,
    best_candidate_error,
    result_fingerprint,
    telemetry_reference,
    truth_position,
)

if TYPE_CHECKING:
    pass

__all__ = [
    "ALL_FRAMES",
    "FlightOptions",
    "FlightStopped",
    "Progress",
    "check_flight",
    "fly",
    "fly_prepared",
    "run_flight",
    "signals_noted",
]

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class FlightOptions:
    """How a flight is flown: ``frames`` (None: all, in order), ``progress`` (called with the
    frames done and those to fly), whether each result keeps its inlier correspondences, and
    ``keep_stopped``: Ctrl-C or SIGTERM during the frames raises :class:`FlightStopped` with
    the outcomes of those done (else the interrupt as it came), and :func:`fly_prepared`
    keeps each frame's result line as it is flown, so that a run killed outright keeps them
    too (:func:`~c3_matcher_tools.run.results_file.appending_results`)."""

    frames: Sequence[FrameRecord] | None = None
    progress: Progress | None = None
    with_correspondences: bool = True
    keep_stopped: bool = False


ALL_FRAMES = FlightOptions()


class FlightStopped(KeyboardInterrupt):
    """Ctrl-C (SIGINT) or SIGTERM stopped a flight part-way (``keep_stopped``): ``signum``, the
    outcomes of the frames done and how many it was to fly; :func:`fly_prepared` adds ``run``,
    those outcomes as a :class:`FlightRun` whose ``complete`` is False."""

    def __init__(
        self,
        signum: int,
        done: Sequence[FrameOutcome],
        planned: int,
        run: FlightRun | None = None,
    ) -> None:
        super().__init__(f"stopped after {len(done)} of {planned} frames")
        self.signum = signum
        self.done = tuple(done)
        self.planned = planned
        self.run = run


def run_flight(
    matcher: CrossDomainMatcher,
    dataset: FlightDataset,
    options: FlightOptions = ALL_FRAMES,
    *,
    kept: KeepFrame | None = None,
) -> list[FrameOutcome]:
    """Match every frame (or ``options.frames``) in order, as ``options`` says; tiles are read
    lazily from the store. ``kept``: called with each frame's outcome once it is flown, before
    the progress is said."""
    todo = list(dataset.frames if options.frames is None else options.frames)
    progress, with_correspondences = options.progress, options.with_correspondences
    outcomes: list[FrameOutcome] = []
    # one listener for the flight, not one added and removed inside each frame's timing
    with dataset.open_store() as store, signals_noted() as noted, drops_heard() as heard:
        try:
            for n, frame in enumerate(todo, start=1):
                flown = _fly_frame(matcher, dataset, frame, store, heard, with_correspondences)
                outcomes.append(flown)
                if kept is not None:
                    kept(flown)
                if progress is not None:
                    progress(n, len(todo))
        except KeyboardInterrupt as exc:
            if not options.keep_stopped or not noted:
                raise
            raise FlightStopped(noted[-1], outcomes, len(todo)) from exc
    return outcomes


@contextlib.contextmanager
def signals_noted() -> Iterator[list[int]]:
    """The SIGINT and SIGTERM that come while the block runs, in order, each then handled as
    before (raising ``KeyboardInterrupt``, as the command line has it); the handlers as they
    were afterwards, so that a second one while a stopped run's results are written stops it
    at once. Signals left alone where handlers cannot be set (not the main thread) or the
    current one is not Python's."""
    noted: list[int] = []
    previous: dict[int, Callable[..., object]] = {}

    def note(signum: int, frame: object) -> None:
        noted.append(signum)
        previous[signum](signum, frame)

    for signum in (signal.SIGINT, signal.SIGTERM):
        handler = signal.getsignal(signum)
        if callable(handler):
            with contextlib.suppress(ValueError):  # not the main thread: left alone
                signal.signal(signum, note)
                previous[signum] = handler
    try:
        yield noted
    finally:
        for number, before in previous.items():
            signal.signal(number, before)


def _fly_frame(
    matcher: CrossDomainMatcher,
    dataset: FlightDataset,
    frame: FrameRecord,
    store: MBTilesStore,
    heard: dict[int, HeardDrop],
    with_correspondences: bool,
) -> FrameOutcome:
    """The frame matched and scored; ``heard``: the flight's listener for dropped candidates
    (emptied here before the frame's ``match``)."""
    where = _Where(frame.has_truth, truth_position(dataset, frame), telemetry_reference(frame))
    try:
        nav = dataset.nav_frame(frame)
    except InvalidInputError as exc:  # a damaged or vanished image: the camera's loss, not C3's
        return where.outcome(frame, FrameStatus.UNREADABLE, 0.0, error=str(exc))
    rerank = dataset.rerank(frame, store)
    heard.clear()
    t0 = time.perf_counter()
    failure: tuple[FrameStatus, Exception, int] | None = None
    try:
        result = matcher.match(nav, rerank, dataset.calibration)
    except InsufficientInliersError as exc:
        failure = (FrameStatus.INSUFFICIENT, exc, exc.best_inlier_count)
    except MatcherBackboneError as exc:
        failure = (FrameStatus.BACKBONE_ERROR, exc, 0)
    elapsed = (time.perf_counter() - t0) * 1e3
    dropped = tuple(
        DroppedCandidate(i, drop.event.get("tile_id"), drop.reason, _cause(drop.event))
        for i, drop in sorted(heard.items())
    )
    where = replace(where, candidates=len(rerank.candidates), dropped=dropped)
    if failure is not None:
        status, error, best_count = failure
        ambiguous = error.ambiguity if isinstance(error, AmbiguousMatchError) else None
        return where.outcome(
            frame, status, elapsed, error=str(error), best_count=best_count, ambiguous=ambiguous
        )
    return _matched(dataset, frame, result, elapsed, where, with_correspondences)


def _cause(event: Mapping[str, Any]) -> str:
    """What a run's summary counts a drop under: the step and error type of a backbone error
    (``"tile_decode TileDigestError"``), else no inliers or a refusal on geometry."""
    kind = event.get("kind")
    if kind == MATCHER_ZERO_INLIERS:
        return "no inliers"
    if kind == MATCHER_GEOMETRY_REFUSED:
        return "refused on geometry"
    error_type = str(event.get("error", "")).split(":", 1)[0]
    return f"{event.get('phase')} {error_type}".strip()


@dataclass(frozen=True)
class _Where:
    """Where a frame truly looks (``truth``, lat/lon: None without ground truth) and where its
    telemetry says it looks: what each outcome of the frame is scored against; once matched,
    the candidates it was given and those the matcher dropped."""

    has_truth: bool
    truth: tuple[float, float] | None
    telemetry: TelemetryReference | None
    candidates: int = 0
    dropped: tuple[DroppedCandidate, ...] = ()

    def outcome(
        self,
        frame: FrameRecord,
        status: FrameStatus,
        elapsed_ms: float,
        *,
        error: str | None = None,
        best_count: int = 0,
        matched: _Matched | None = None,
        ambiguous: str | None = None,
    ) -> FrameOutcome:
        """The frame's outcome: ``matched``, or ``status`` and the ``error`` that says why not
        (``best_count``: the best candidate's inliers, below the threshold unless the frame was
        refused as ``ambiguous``: the rival candidate, in ``AmbiguousMatchError``'s words)."""
        tele = self.telemetry
        est = None if matched is None else matched.estimate
        return FrameOutcome(
            frame.index,
            str(frame.frame_id),
            status,
            elapsed_ms,
            frame.true_tile_present,
            0 if matched is None else matched.result.per_candidate[0].inlier_count,
            None if matched is None else matched.best_input,
            matched is not None and matched.best_input == frame.true_index,
            math.nan if matched is None else matched.mean_error_px,
            math.nan if matched is None else matched.result.reprojection_residual_px,
            _fingerprint(status, matched, best_count, ambiguous),
            error,
            None if matched is None else matched.as_json,
            has_truth=self.has_truth,
            est_lat=None if est is None else est[0],
            est_lon=None if est is None else est[1],
            truth_lat=None if self.truth is None else self.truth[0],
            truth_lon=None if self.truth is None else self.truth[1],
            position_error_m=_distance_m(est, self.truth),
            insufficient_best=best_count,
            telemetry_lat=None if tele is None else tele.lat,
            telemetry_lon=None if tele is None else tele.lon,
            telemetry_error_m=_distance_m(est, None if tele is None else (tele.lat, tele.lon)),
            gnss_accuracy_m=None if tele is None else tele.gnss_accuracy_m,
            gnss_degraded=None if tele is None else tele.gnss_degraded,
            attitude_assumed=tele is not None and tele.attitude_assumed,
            candidates=self.candidates,
            dropped=self.dropped,
            ambiguous=ambiguous,
            captured_at_ns=frame.captured_at_ns,
        )


@dataclass(frozen=True)
class _Matched:
    """A frame's result and what scoring it gave: the best candidate's input index, its inlier
    error against ground truth, the result as JSON and where it puts the frame (lat, lon)."""

    result: MatchResult
    best_input: int
    mean_error_px: float
    as_json: dict[str, Any]

    @property
    def estimate(self) -> tuple[float, float] | None:
        if "centre_lat" not in self.as_json:
            return None
        return float(self.as_json["centre_lat"]), float(self.as_json["centre_lon"])


def _fingerprint(
    status: FrameStatus, matched: _Matched | None, best_count: int, ambiguous: str | None
) -> str:
    if matched is not None:
        return result_fingerprint(matched.result)
    if status != FrameStatus.INSUFFICIENT:
        return ""
    return result_fingerprint(None, best_count, ambiguous)


def _distance_m(a: tuple[float, float] | None, b: tuple[float, float] | None) -> float:
    """Metres between two (lat, lon); NaN when either is missing."""
    if a is None or b is None:
        return math.nan
    return float(haversine_m([[a[1], a[0]]], [[b[1], b[0]]])[0])


def _matched(
    dataset: FlightDataset,
    frame: FrameRecord,
    result: MatchResult,
    elapsed_ms: float,
    where: _Where,
    with_correspondences: bool,
) -> FrameOutcome:
    best_input, mean_err = best_candidate_error(dataset, frame, result)
    size = dataset.candidate_size_px
    as_json = result_to_json(
        result,
        with_correspondences=False,
        calibration=dataset.calibration,
        tile_sizes=[(size, size)] * len(frame.candidates),  # store windows: placed on the grid
    )
    for entry, candidate in zip(as_json["per_candidate"], result.per_candidate, strict=True):
        if with_correspondences:  # the result's arrays, lists only when written (replay_memory.py)
            entry["inlier_correspondences"] = candidate.inlier_correspondences
    matched = _Matched(result, best_input, mean_err, as_json)
    return where.outcome(frame, FrameStatus.OK, elapsed_ms, matched=matched)


def fly(
    settings: C3Settings,
    strategy: str,
    dataset: FlightDataset,
    out_dir: Path,
    *,
    plugin_host: PluginHost,
    overrides: Overrides = NO_OVERRIDES,
    options: FlightOptions = ALL_FRAMES,
) -> FlightRun:
    """Open ``strategy`` (:func:`~c3_matcher_tools.run.matcher.prepare_matcher`: composed
    before ``out_dir`` is touched, so one that cannot start leaves it as it was), then fly it
    as ``options`` says with its FDR and logs under ``out_dir`` (:func:`fly_prepared`)."""
    with prepare_matcher(
        settings, strategy, plugin_host=plugin_host, overrides=overrides
    ) as prepared:
        return fly_prepared(prepared, dataset, out_dir, plugin_host=plugin_host, options=options)


def fly_prepared(
    prepared: PreparedMatcher,
    dataset: FlightDataset,
    out_dir: Path,
    *,
    plugin_host: PluginHost,
    options: FlightOptions = ALL_FRAMES,
) -> FlightRun:
    """Start ``prepared`` in ``out_dir`` (:meth:`~PreparedMatcher.start`: a fresh FDR and log),
    fly it as ``options`` says and time it: start-up is composing the matcher and opening its
    FDR, wall time that and flying (s). With ``options.keep_stopped``, a flight stopped
    part-way raises :class:`FlightStopped` holding the run of the frames done, and each
    frame's result line is appended to ``results.jsonl.partial`` in ``out_dir`` as it is
    flown (:func:`_kept_as_flown`), which writing the run's ``results.jsonl`` removes."""
    started = time.perf_counter()
    prepared.start(out_dir)
    startup_s = prepared.startup_s + time.perf_counter() - started
    reads = strategy_reads_lightglue(prepared.settings, plugin_host, prepared.strategy) is not False

    def flight_run(outcomes: Sequence[FrameOutcome], planned: int | None = None) -> FlightRun:
        ran = strategy_settings(prepared.settings, prepared.strategy, plugin_host)
        return FlightRun(
            prepared.strategy,
            ran.matcher.model_dump(mode="json"),
            tuple(outcomes),
            startup_s,
            prepared.startup_s + time.perf_counter() - started,
            ran.lightglue.model_dump(mode="json") if reads else {},  # none applied: none said
            planned,
            prepared.log_lines_lost,
            prepared.provenance,
            prepared.keypoint_budget,
        )

    try:
        with _kept_as_flown(out_dir, options.keep_stopped) as kept:
            outcomes = run_flight(prepared.matcher, dataset, options, kept=kept)
    except FlightStopped as stop:
        run = flight_run(stop.done, stop.planned)
        raise FlightStopped(stop.signum, stop.done, stop.planned, run) from stop.__cause__
    return flight_run(outcomes)


def _kept_as_flown(
    out_dir: Path, keep_stopped: bool
) -> contextlib.AbstractContextManager[KeepFrame | None]:
    """Where a flight whose frames done are kept (``keep_stopped``) appends each frame's result
    line as it is flown: the partial file of ``out_dir``'s results, flushed to disk, so that a
    run killed outright (SIGKILL, out of memory) keeps them as well as one stopped. None for
    one whose frames are not kept (eval's second run), an earlier partial file there removed:
    no earlier run's results stand beside this run's FDR."""
    results = out_dir / RESULTS_FILE
    if keep_stopped:
        return appending_results(results)
    partial_results(results).unlink(missing_ok=True)
    return contextlib.nullcontext()


def check_flight(dataset: FlightDataset, frames: Sequence[FrameRecord]) -> None:
    """What a run of ``frames`` will read, checked before the run starts: the dataset's tile
    store opens (an MBTiles file with its tables), and each frame's image is a readable file
    whose header names a decodable format within ``dataset.max_image_pixels``, of the size its
    calibration was made for (both sizes named). ``InvalidInputError`` naming the first input
    that is not. Only the headers are read: nothing is decoded."""
    dataset.open_store().close()
    for frame in frames:
        path = dataset.root / frame.image
        width, height = _header_size(path, dataset.max_image_pixels)
        _refuse_another_size(dataset, frame, width, height)


def _header_size(path: Path, max_pixels: int) -> tuple[int, int]:
    """(width, height) of the image file ``path`` from its header, as ``read_image`` would
    refuse it (missing, not a regular file, empty, unreadable, not an image, too large)."""
    if not path.exists():
        raise InvalidInputError(str(path), "no such image file")
    MmapTileHandle(path, max_pixels=max_pixels)  # a regular file, not empty
    try:
        with path.open("rb") as fh:
            size = image_file_size(fh)
    except OSError as exc:
        raise InvalidInputError(
            str(path), f"cannot read image file: {exc.strerror or exc}"
        ) from exc
    if size is None or min(size) <= 0:
        raise InvalidInputError(str(path), f"not a decodable image ({DECODABLE_FORMATS})")
    if size[0] * size[1] > max_pixels:
        raise InvalidInputError(
            str(path),
            f"image of {size[0]}x{size[1]} px exceeds the limit of {max_pixels} px "
            "([matcher] max_image_pixels)",
        )
    return size


def _refuse_another_size(dataset: FlightDataset, frame: FrameRecord, w: int, h: int) -> None:
    """A calibration made for another image size is bad input (exit 2) naming both sizes,
    not a backbone failure on every frame."""
    cw, ch = dataset.calibration.image_size
    if (cw, ch) != (w, h):
        raise InvalidInputError(
            str(dataset.root / str(dataset.meta["calibration"])),
            f"image_size is {cw}x{ch} px but frame {frame.image} is {w}x{h} px "
            f"({CALIBRATION_SIZE_FIX})",
        )
