"""The ``c3-flight/1`` dataset written from a log's track and its images
(:func:`write_imported_flight`), with the checks every import makes of them."""

from __future__ import annotations

import math
import uuid
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.dto import CameraCalibration
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.atomic import atomic_directory, check_output_dir
from c3_matcher_tools.dataset.format import dataset_name
from c3_matcher_tools.dataset.proposals import StoreProposals, imported_frame, propose_from_store
from c3_matcher_tools.dataset.sources.frames import Frame, assemble_frames
from c3_matcher_tools.dataset.sources.images import image_problem, readable_shots
from c3_matcher_tools.dataset.sources.options import ImportOptions, ImportReport, ProposalOptions
from c3_matcher_tools.dataset.sources.pairing import Pairing, match_shots
from c3_matcher_tools.dataset.sources.track import LogTrack, Shot
from c3_matcher_tools.dataset.telemetry import TelemetryRow
from c3_matcher_tools.dataset.writing import place_store, write_dataset, write_file

__all__ = ["MAX_OWN_GPS_OFFSET_M", "image_problem", "write_imported_flight"]


def write_imported_flight(
    track: LogTrack,
    shots: Sequence[Shot],
    options: ImportOptions,
    out: Path,
    *,
    name: str | None = None,
    force: bool = False,
    attitude_of: Callable[[Shot, float], tuple[float, float, float] | None] | None = None,
    spec: dict[str, Any] | None = None,
    skipped: Sequence[tuple[str, str]] = (),
) -> ImportReport:
    """Match ``shots`` to ``track``, propose candidates from the store around each frame's look
    point and write the ``c3-flight/1`` dataset ``out`` atomically (everything is checked
    first); returns what was done (``skipped``: images the caller already set aside, with the
    reason). Raises InvalidInputError naming the input at fault."""
    out = Path(out)
    proposer = options.proposal
    check_output_dir(out, force=force, inputs=(track.source, proposer.store, options.dem))
    label = dataset_name(name, out)
    placed_frames, skipped, pairing = _placed(track, shots, options, attitude_of, skipped)
    how, notes = pairing.how, (*track.notes, *pairing.notes)
    calibration = options.calibration
    frames, rows, proposed, outside = _propose(track, placed_frames, proposer, calibration)
    skipped = [*skipped, *outside]
    images = [f.shot.read() for f in frames]  # each checked before it met the log
    zoom, proposals = proposed.zoom, proposed.looks
    attribution, tiles_source = proposed.attribution, proposed.tiles_source
    base = uuid.uuid5(uuid.NAMESPACE_URL, f"c3-flight-import:{label}")
    t0 = frames[0].t_s
    records = []
    for i, (f, row, proposal) in enumerate(zip(frames, rows, proposals, strict=True)):
        heights = {"alt_m": None if not math.isfinite(f.alt_m) else f.alt_m}
        extra = {"height_source": f.height_source, "flags": list(f.flags), **f.gnss}
        records.append(
            imported_frame(
                i, row, t0, base, f.shot.suffix, proposal, proposer, heights=heights, extra=extra
            )
        )
    with atomic_directory(out, force=force) as tmp:
        placed = place_store(tmp, proposer.store, link=True)  # the import's record says how
        report = _report(out, track, frames, skipped, pairing, options, zoom, [*notes, placed])
        meta = {
            "name": label,
            "candidate_size_px": proposer.candidate_size_px,
            "zoom": zoom,
            "tiles_source": tiles_source,
            "frames_source": f"imported: {Path(track.source).name} ({track.kind})",
            "spec": {**_spec(track, how, options, zoom), **(spec or {})},
            "import": {k: v for k, v in report.to_json().items() if k != "dataset"},
            "attribution": attribution,
        }
        (tmp / "frames").mkdir()
        for rec, data in zip(records, images, strict=True):
            write_file(tmp / rec.image, data)
        write_dataset(tmp, meta, calibration, records, store=None)
    return report


def _propose(
    track: LogTrack,
    frames: Sequence[Frame],
    proposer: ProposalOptions,
    calibration: CameraCalibration,
) -> tuple[list[Frame], list[TelemetryRow], StoreProposals, list[tuple[str, str]]]:
    """(frames, their telemetry rows, the candidates around each one's look point, the frames
    skipped with why): refused when a look point lies outside the store, unless
    ``--skip-outside`` skips those frames (refused still when no frame is inside)."""
    rows = [
        TelemetryRow(i, f.t_s, f.shot.name, f.lat, f.lon, f.height_m, *f.attitude)
        for i, f in enumerate(frames)
    ]
    proposed = propose_from_store(rows, calibration, proposer)
    inside, proposed, outside = proposed.within(
        rows,
        track.source,
        lambda r: r.image,
        skip=proposer.skip_outside,
        hint=" (log and store of different places?)",
        shown=5,
    )
    return [frames[i] for i in inside], [rows[i] for i in inside], proposed, outside


def _placed(
    track: LogTrack,
    shots: Sequence[Shot],
    options: ImportOptions,
    attitude_of: Callable[[Shot, float], tuple[float, float, float] | None] | None,
    skipped: Sequence[tuple[str, str]],
) -> tuple[list[Frame], list[tuple[str, str]], Pairing]:
    """The frames placed on the log (refused when none is, when the images' own GPS says
    another flight, or when no frame has a height above ground), every image skipped with its
    reason (a file that is not a readable image before the images meet the log, so that it is
    never counted among them), and how the images met the log's clock."""
    options.proposal.check_store()
    if not shots:
        raise InvalidInputError("IMAGES", "no image found")
    if track.position is None and track.gnss is None:
        raise InvalidInputError(track.source, "the log holds no position (GNSS or estimator)")
    shots, unreadable, skipped = readable_shots(shots, options.calibration.image_size, skipped)
    if not shots:
        (first, why), others = unreadable[0], unreadable[1:]
        more = ", ".join(f"{n} ({w})" for n, w in others[:3]) + (", ..." if others[3:] else "")
        raise InvalidInputError(
            "IMAGES", f"{first}: {why}" + (f", nor is any other: {more}" if others else "")
        )
    skipped = [*unreadable, *skipped]  # a copy of an unreadable file follows it
    pairing = match_shots(track, shots, options, left_out=unreadable)
    frames, no_pos = assemble_frames(track, pairing.taken, options, attitude_of)
    rank = {s.name: i for i, s in enumerate(shots)}
    every = [*skipped, *sorted([*pairing.skipped, *no_pos], key=lambda x: rank.get(x[0], -1))]
    if not frames:
        raise InvalidInputError(track.source, "no image could be placed: " + _why(every))
    _check_same_flight(track, frames)
    _check_heights(track, frames, options)
    return frames, every, pairing


def _check_heights(track: LogTrack, frames: Sequence[Frame], options: ImportOptions) -> None:
    """Refuse frames none of which is above the ground, saying why: with a ground given, the
    heights its altitudes gave (a ground of another datum or unit than the altitude's);
    without, that one is needed (and a bag's geoid height with it)."""
    if any(math.isfinite(f.height_m) and f.height_m > 0 for f in frames):
        return
    said = f"{track.source}: no height above ground for any frame"
    sources = ", ".join(sorted({f.height_source for f in frames}))
    heights = [f.height_m for f in frames if math.isfinite(f.height_m)]
    if options.dem is None and options.ground_elevation_m is None:
        geoid = ", with --geoid-height (its altitude is above the ellipsoid)"
        raise InvalidInputError(
            "--ground-elevation",
            f"{said} (heights {sources}): give --ground-elevation (the ground's altitude above "
            f"sea level, m) or --dem{geoid if track.ellipsoidal else ''}",
        )
    option = "--dem" if options.dem is not None else "--ground-elevation"
    if not heights:
        raise InvalidInputError(option, f"{said} (heights {sources})")
    geoid = " and the geoid height" if track.ellipsoidal else ""
    raise InvalidInputError(
        option,
        f"{said}: {sources} gave heights from {min(heights):.1f} to {max(heights):.1f} m (none "
        f"above ground): check the ground's datum{geoid} and units ({option} is the ground's "
        "altitude above sea level, in metres)",
    )


def _spec(track: LogTrack, how: str, options: ImportOptions, zoom: int) -> dict[str, Any]:
    return {
        "kind": "import",
        "log": Path(track.source).name,
        "log_kind": track.kind,
        "time_source": how,
        "time_offset_s": options.time_offset_s,  # as given: None when not
        **options.proposal.spec_json(zoom),
    }


def _report(
    out: Path,
    track: LogTrack,
    frames: Sequence[Frame],
    skipped: Sequence[tuple[str, str]],
    pairing: Pairing,
    options: ImportOptions,
    zoom: int,
    notes: Sequence[str],
) -> ImportReport:
    """What the import did: the time offset applied to the images' times is the camera
    clock's found one where one was sought (:attr:`Pairing.found_offset_s`), else
    ``--time-offset`` (0 when not given), and the report says which."""
    offset, origin = options.offset_s, "not given" if options.time_offset_s is None else "given"
    if pairing.found_offset_s is not None:
        offset, origin = pairing.found_offset_s, "found"
    return ImportReport(
        dataset=str(out),
        source=Path(track.source).name,
        kind=track.kind,
        frames=len(frames),
        skipped=tuple(skipped),
        time_source=pairing.how,
        time_offset_s=offset,
        height_sources=_count(f.height_source for f in frames),
        attitude_assumed=tuple(i for i, f in enumerate(frames) if "attitude_assumed" in f.flags),
        height_assumed=tuple(i for i, f in enumerate(frames) if "height_assumed" in f.flags),
        gnss_degraded=tuple(i for i, f in enumerate(frames) if "gnss_degraded" in f.flags),
        zoom=zoom,
        notes=tuple(notes),
        time_offset_origin=origin,
    )


MAX_OWN_GPS_OFFSET_M = 500.0
"""Images whose own GPS lies farther than this (median) from the log's position at their
times belong to another flight (or need a time offset)."""


def _check_same_flight(track: LogTrack, frames: Sequence[Frame]) -> None:
    """Refuse images whose own GPS (EXIF) disagrees with the log's position at their times."""
    from c3_matcher.georef import haversine_m

    if track.per_image:
        return
    own = [f for f in frames if "lat" in f.shot.own and "lon" in f.shot.own]
    if not own:
        return
    d = haversine_m(
        [[f.shot.own["lon"], f.shot.own["lat"]] for f in own], [[f.lon, f.lat] for f in own]
    )
    median = float(np.median(d))
    if median > MAX_OWN_GPS_OFFSET_M:
        raise InvalidInputError(
            track.source,
            f"the images' own GPS lies {median / 1000:.1f} km (median of {len(own)}) from the "
            "log's position at their times: images and log of different flights, or a time "
            "offset to give (--time-offset)",
        )


def _count(values: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for v in values:
        out[v] = out.get(v, 0) + 1
    return out


def _why(skipped: Sequence[tuple[str, str]]) -> str:
    reasons = _count(r.split(" at ")[0] if r.startswith("no position") else r for _, r in skipped)
    return "; ".join(f"{r} ({n})" for r, n in list(reasons.items())[:3]) or "no image"
