"""How images meet a log's clock: camera triggers (in order, or each photo the trigger nearest
its own time), the images' own UTC times, or file order (:func:`match_shots`)."""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np

from c3_matcher.arrays import F64
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.sources.camera_clock import found_offset, nearest_triggers, shot_names
from c3_matcher_tools.dataset.sources.options import ImportOptions
from c3_matcher_tools.dataset.sources.track import LogTrack, Shot

__all__ = ["Pairing", "match_shots", "same_times", "times_apart", "utc_text"]


@dataclass(frozen=True, slots=True)
class Pairing:
    """How images met a log's clock: each paired image with its time on the log's clock, each
    image left out with the reason, how they were paired, and what else the import should say
    (a photo whose capture time lies apart from the others'); ``found_offset_s``: the camera
    clock's offset found and added to the images' own times (None when none was sought: one
    given, or the images not paired by their own times)."""

    taken: tuple[tuple[Shot, float], ...]
    skipped: tuple[tuple[str, str], ...]
    how: str
    notes: tuple[str, ...] = ()
    found_offset_s: float | None = None


def times_apart(times: Sequence[float], gap_s: float) -> list[int]:
    """The indices of the ``times`` that lie apart from the rest: in time order the times split
    where two neighbours are more than ``gap_s`` apart, and those outside the largest group (of
    equal ones the latest: a camera clock that was reset went back to an epoch) are apart.
    Empty when no two neighbours are that far apart."""
    groups: list[list[int]] = []
    for i in sorted(range(len(times)), key=lambda k: times[k]):
        if groups and times[i] - times[groups[-1][-1]] <= gap_s:
            groups[-1].append(i)
        else:
            groups.append([i])
    flight: set[int] = set()
    for group in groups:  # the largest, of equal ones the latest
        if len(group) >= len(flight):
            flight = set(group)
    return [i for i in range(len(times)) if i not in flight]


def same_times(times: Sequence[float]) -> list[tuple[int, int]]:
    """Each (a, b) of indices of ``times`` that state the same time, neighbours in time order
    (ties in index order). Two records at one time cannot both be placed on a clock: each would
    take the other's pose, so the telemetry CSV's rows and the images placed by their own times
    are refused on them alike."""
    order = sorted(range(len(times)), key=lambda k: (times[k], k))
    return [(a, b) for a, b in itertools.pairwise(order) if times[a] == times[b]]


def utc_text(t_s: float) -> str:
    """UTC seconds as ``1970-01-01 00:00:03 UTC`` (as seconds when no calendar date)."""
    try:
        return datetime.fromtimestamp(t_s, UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
    except (OverflowError, OSError, ValueError):
        return f"{t_s:.0f} s"


_ORDER_HINT = "--interval (s between images) and --time-offset (log time of the first image)"


def _no_time_source(track: LogTrack, shots: Sequence[Shot], untimed: Sequence[Shot]) -> str:
    """Why ``auto`` finds no way to put images without a camera trigger on the log's clock, and
    the options that would."""
    n, timed = len(shots), len(shots) - len(untimed)
    damaged = f" (the log is damaged or truncated: {track.damage})" if track.damage else ""
    head = f"{track.source}: no camera trigger in the log{damaged}"
    if not timed:
        return f"{head}, and none of the {n} images states a capture time: give {_ORDER_HINT}"
    if track.utc_offset_s is None:
        return (
            f"{head}, and it states no UTC time (no GNSS time) to meet the images' own times: "
            f"give {_ORDER_HINT}"
        )
    return (
        f"{head}, and {len(untimed)} of the {n} images state no capture time "
        f"({shot_names(untimed)}): give --time-source exif to import the {timed} that do by their "
        f"own time, or {_ORDER_HINT} to place all {n} in file order"
    )


def _trigger_count_refusal(
    track: LogTrack,
    shots: Sequence[Shot],
    triggers: F64,
    untimed: Sequence[Shot],
    left_out: Sequence[tuple[str, str]],
) -> str:
    """Why ``auto`` will not pair ``shots`` with a different number of ``triggers``: the counts
    (and the files ``left_out`` of them, with why), why order is wrong, why time cannot be used,
    and the ways out."""
    n = len(shots)
    if len(untimed) == n:
        why = f"none of the {n} images states a capture time"
    elif untimed:
        why = f"{len(untimed)} of the {n} images state no capture time ({shot_names(untimed)})"
    else:
        why = "the log states no UTC time (no GNSS time)"
    ways = ["remove the images without a trigger"]
    if track.utc_offset_s is not None and len(untimed) < n:
        those = f"the {n - len(untimed)} that state one, " if untimed else ""
        ways.append(f"give --time-source exif ({those}each by its own time)")
    ways.append("give --time-source trigger to pair them in order anyway")
    damaged = f" (the log is damaged or truncated: {track.damage})" if track.damage else ""
    counted = f"{n} image(s)"
    if left_out:
        shown = ", ".join(f"{name} ({why})" for name, why in left_out[:3])
        more = f" and {len(left_out) - 3} more" if len(left_out) > 3 else ""
        counted += f", not counting {shown}{more}"
    return (
        f"{track.source}: {triggers.size} camera trigger(s) in the log{damaged} but {counted}: "
        "pairing them in order would put every image after a missing or extra one on another "
        f"image's pose, and they cannot be paired by time ({why}); "
        + ", ".join(ways[:-1])
        + ", or "
        + ways[-1]
    )


def _unpaired(images: int, triggers: int) -> str:
    """``"2 image(s) left without a trigger; 1 trigger(s) left without an image"``, the parts
    that are not 0 ("none left unpaired" when both are)."""
    parts = [f"{images} image(s) left without a trigger"] if images else []
    parts += [f"{triggers} trigger(s) left without an image"] if triggers else []
    return "; ".join(parts) or "none left unpaired"


def _tolerance(triggers: F64, options: ImportOptions) -> float:
    """How far an image's own time, moved by the camera clock's offset, may be from its
    trigger, and how wide the window is in which that offset is sought
    (:func:`~c3_matcher_tools.dataset.sources.camera_clock.fit_camera_clock`): ``--max-gap``
    (default 1 s: the spread of whole-second EXIF times, the coarsest a camera states) but at
    most half the median spacing of the triggers, so that an image is never nearer its
    neighbour's trigger than its own and no window holds two shifts by a whole interval. Both
    bounds follow from the times' resolution and the triggers' own rate, whatever the
    flight."""
    steps = np.diff(triggers)
    steps = steps[steps > 0]
    return min(options.max_gap_s, float(np.median(steps)) / 2 if steps.size else math.inf)


def _own_times(track: LogTrack, shots: Sequence[Shot], options: ImportOptions) -> list[float]:
    """The images' own (UTC) times on the log's clock, ``--time-offset`` added."""
    assert track.utc_offset_s is not None
    return [float(s.t_s or 0.0) - track.utc_offset_s + options.offset_s for s in shots]


def _triggers_by_time(
    track: LogTrack, shots: Sequence[Shot], triggers: F64, options: ImportOptions
) -> Pairing:
    """Each image the trigger nearest its own time moved by the camera clock's offset, within
    :func:`_tolerance` (:mod:`~c3_matcher_tools.dataset.sources.camera_clock`): a
    ``--time-offset`` given (0 too: the camera's clock is the log's) is used as given, else the
    offset is found (``found_offset``) and ``how`` states it; refused when no image meets a
    trigger."""
    tol = _tolerance(triggers, options)
    own = _own_times(track, shots, options)
    found = 0.0
    said = f"--time-offset {options.offset_s:+g} s as given"
    if options.time_offset_s is None:
        found, said = found_offset(track, shots, triggers, own, tol)
    taken, skipped = nearest_triggers(shots, [t + found for t in own], triggers, tol)
    if not taken:
        raise InvalidInputError(
            "--time-source",
            f"{track.source}: {triggers.size} camera trigger(s) in the log but {len(shots)} "
            f"image(s), and no image's own time lies within {tol:g} s of a trigger (images at "
            f"{min(own):.1f} .. {max(own):.1f} s, triggers at {triggers[0]:.1f} .. "
            f"{triggers[-1]:.1f} s on the log's clock): the camera's clock is off "
            "(--time-offset, the seconds added to the images' own times), or give "
            "--time-source trigger to pair them in order",
        )
    left = _unpaired(len(shots) - len(taken), triggers.size - len(taken))
    how = (
        f"camera trigger nearest each image's own UTC time, {said}, within {tol:g} s "
        f"({triggers.size} in the log, {len(shots)} image(s): {left})"
    )
    sought = found if options.time_offset_s is None else None
    return Pairing(tuple(taken), tuple(skipped), how, found_offset_s=sought)


def _as_many_triggers(shots: Sequence[Shot], triggers: F64, options: ImportOptions) -> Pairing:
    """As many photos as triggers, each stating its own time: the photos take the triggers in
    the order of those times (ties, as whole-second EXIF times give, in file order), not by file
    name, which need not sort in capture order; each photo at its trigger's time. Order alone:
    a camera clock off the log's, or times truncated to the second, move no photo onto another's
    trigger, as pairing each with the trigger nearest its time could; nor does ``--time-offset``
    (added to the photos' own times, it leaves their order: ``how`` says so). A photo whose time
    lies apart from the others' (:func:`times_apart`: farther than the triggers' whole span, a
    clock reset) does not sort among them: it keeps its place in file order, and a note says
    so."""
    counts = f"{triggers.size} in the log, {len(shots)} image(s)"
    times = [float(s.t_s or 0.0) for s in shots]
    apart = set(times_apart(times, float(triggers[-1] - triggers[0]) + options.max_gap_s))
    in_time = iter(sorted((i for i in range(len(shots)) if i not in apart), key=times.__getitem__))
    ordered = [shots[i if i in apart else next(in_time)] for i in range(len(shots))]  # stable
    how = f"camera trigger ({counts})"
    if any(a is not b for a, b in zip(ordered, shots, strict=True)):
        how = f"camera trigger in the images' capture order, not their file order ({counts})"
    taken = tuple((s, float(t)) for s, t in zip(ordered, triggers, strict=True))
    if options.offset_s:  # the report shows the offset given: say what it did
        how += (
            "; --time-offset moves the photos' own times, not their order: each keeps its trigger"
        )
    return Pairing(taken, (), how, (_apart_note(shots, apart),) if apart else ())


def _apart_note(shots: Sequence[Shot], apart: set[int]) -> str:
    """What :func:`_as_many_triggers` says of the photos whose times lie ``apart``."""
    odd = [shots[i] for i in sorted(apart)]
    rest = [float(s.t_s or 0.0) for i, s in enumerate(shots) if i not in apart]
    when = ", ".join(f"{s.name} at {utc_text(float(s.t_s or 0.0))}" for s in odd[:3])
    more = f" and {len(odd) - 3} more" if len(odd) > 3 else ""
    return (
        f"{when}{more}: a capture time apart from the other photos' ({utc_text(min(rest))} .. "
        f"{utc_text(max(rest))}) by more than the camera triggers' span (a camera clock "
        "reset?): paired by its place in file order, the others by their capture times"
    )


def _auto_source(
    track: LogTrack,
    shots: Sequence[Shot],
    triggers: F64,
    options: ImportOptions,
    left_out: Sequence[tuple[str, str]],
) -> str:
    """What ``--time-source auto`` uses (see :func:`match_shots`), or refused saying why."""
    untimed = [s for s in shots if s.t_s is None]
    if shots and all("relative_s" in s.own for s in shots):
        return "order"  # a video's frames keep the video's clock
    if triggers.size == len(shots) and triggers.size:
        return "trigger" if untimed else "as many triggers"
    if triggers.size:
        if untimed or track.utc_offset_s is None:
            raise InvalidInputError(
                "--time-source", _trigger_count_refusal(track, shots, triggers, untimed, left_out)
            )
        return "trigger time"
    if shots and not untimed and track.utc_offset_s is not None:
        return "exif"
    if options.interval_s is not None:
        return "order"
    raise InvalidInputError("--time-source", _no_time_source(track, shots, untimed))


def _in_file_order(
    track: LogTrack, shots: Sequence[Shot], triggers: F64, options: ImportOptions
) -> Pairing:
    """The triggers in order, ``--time-offset`` added to their times (``--time-source
    trigger``, or images that state no time of their own)."""
    if not triggers.size:
        raise InvalidInputError("--time-source", f"{track.source}: no camera trigger")
    off = options.offset_s
    taken = tuple((s, float(t) + off) for s, t in zip(shots, triggers, strict=False))
    skipped = tuple(
        (s.name, f"no camera trigger left ({triggers.size} in the log)")
        for s in shots[triggers.size :]
    )
    how = f"camera trigger ({triggers.size} in the log, {len(shots)} image(s))"
    if triggers.size != len(shots):
        left = _unpaired(max(len(shots) - triggers.size, 0), max(triggers.size - len(shots), 0))
        how = (
            f"camera trigger in file order, as asked ({triggers.size} in the log, "
            f"{len(shots)} image(s): {left})"
        )
    return Pairing(taken, skipped, how)


def _by_own_time(track: LogTrack, shots: Sequence[Shot], options: ImportOptions) -> Pairing:
    """Each image at its own UTC time on the log's clock, ``--time-offset`` added."""
    if track.utc_offset_s is None:
        raise InvalidInputError(
            "--time-source", f"{track.source}: the log states no UTC time (no GNSS time)"
        )
    taken = tuple(
        (s, s.t_s - track.utc_offset_s + options.offset_s) for s in shots if s.t_s is not None
    )
    if not track.per_image:  # photos that state their own position keep it, whatever the time
        _refuse_same_times(track, [(s, t) for s, t in taken if "t_s" in s.own])
    skipped = tuple((s.name, "the image states no capture time") for s in shots if s.t_s is None)
    how = "the images' own UTC time stamps against the log's UTC time"
    photos = not track.per_image and any("t_s" in s.own for s, _ in taken)
    return Pairing(taken, skipped, how, (_unchecked_clock(options),) if photos else ())


def _unchecked_clock(options: ImportOptions) -> str:
    """What an import placing photos by their own times says of the camera's clock: a constant
    offset from the log's is one number the log cannot show without camera triggers to meet
    (every frame moves along the track alike, so nothing looks wrong), and no offset is
    guessed."""
    added = f", --time-offset {options.offset_s:+g} s added" if options.offset_s else ""
    return (
        f"the photos' capture times are the camera's clock as it states them{added}: no camera "
        "trigger meets them, so nothing here shows that clock's offset from the log's, and an "
        "offset of c s puts every frame where the vehicle was c s earlier or later (the distance "
        "flown in c s); --time-offset corrects a known one"
    )


def _refuse_same_times(track: LogTrack, taken: Sequence[tuple[Shot, float]]) -> None:
    """Refuse photos that state the same capture time in their own metadata (whole-second EXIF
    times of several shots a second, a camera clock that stalled): on the log's clock they would
    take one pose. The refusal names them and the time, and the ways out. (A bag's frames that
    share a header stamp are the recorder's, imported each at its stamp and said in the bag's
    notes.)"""
    pairs = same_times([t for _, t in taken])
    if not pairs:
        return
    shown = "; ".join(
        f"{taken[a][0].name} and {taken[b][0].name}: same capture time "
        f"{utc_text(float(taken[a][0].t_s or 0.0))} ({taken[a][1]:.3f} s on the log's clock)"
        for a, b in pairs[:3]
    )
    more = f" (and {len(pairs) - 3} more)" if len(pairs) > 3 else ""
    triggers = track.triggers_s if track.triggers_s is not None else np.zeros(0)
    way = (
        f"--time-source trigger to pair them with the log's {triggers.size} camera trigger(s)"
        if triggers.size
        else f"--time-source order with {_ORDER_HINT} to place them in file order"
    )
    raise InvalidInputError(
        "--time-source",
        f"{shown}{more}: placed by their own times they would take one pose; "
        "fix the camera's clock or its time stamps (several photos a second need sub-second "
        f"times), remove the repeated photos, or give {way}",
    )


def _by_file_order(shots: Sequence[Shot], triggers: F64, options: ImportOptions) -> Pairing:
    """One image every ``--interval`` from ``--time-offset`` on (a video: its own clock)."""
    video = bool(shots) and all("relative_s" in s.own for s in shots)
    if options.interval_s is None and not video:
        raise InvalidInputError("--interval", "file order needs --interval (s between images)")
    step, off = options.interval_s or 0.0, options.offset_s
    taken = tuple((s, off + float(s.own.get("relative_s", i * step))) for i, s in enumerate(shots))
    how = "video clock" if video else f"file order, one image every {step:g} s"
    if video and triggers.size and options.time_source == "auto":
        how += (
            f" (the log's {triggers.size} camera trigger(s), a stills camera's, not used: "
            "--time-source trigger to pair them in order)"
        )
    return Pairing(taken, (), how)


def match_shots(
    track: LogTrack,
    shots: Sequence[Shot],
    options: ImportOptions,
    *,
    left_out: Sequence[tuple[str, str]] = (),
) -> Pairing:
    """Each shot's time on the log's clock, in time order, the shots left out with the reason,
    how they were paired, and what else the import should say (``left_out``: the files set
    aside before, with why, which a refusal of the counts names).

    ``auto``: a video's frames keep the video's clock (the log's camera triggers are a stills
    camera's). Photos take the camera triggers: when the log has exactly as many and every
    photo states its own time, by that time (:func:`_as_many_triggers`), else in file order;
    with another count, each photo the trigger nearest its own UTC time
    (:func:`_triggers_by_time`) when every photo states one and the log states UTC, else
    refused: in order, one missing or extra photo would shift every later one onto another's
    pose. Without triggers: the photos' own UTC times, else file order with ``--interval``.
    ``trigger`` pairs in file order whatever the counts, and ``how`` says how many were left
    unpaired. ``--time-offset`` is added to the images' own times where they are used, else to
    the trigger times or to the file order's start. Raises InvalidInputError when no image
    falls within the log's time span (images of another flight) or the chosen time source
    cannot be used."""
    triggers = track.triggers_s if track.triggers_s is not None else np.zeros(0)
    src = options.time_source
    if src == "auto":
        src = _auto_source(track, shots, triggers, options, left_out)
    if src == "trigger":
        pairing = _in_file_order(track, shots, triggers, options)
    elif src == "as many triggers":
        pairing = _as_many_triggers(shots, triggers, options)
    elif src == "trigger time":
        pairing = _triggers_by_time(track, shots, triggers, options)
    elif src == "exif":
        pairing = _by_own_time(track, shots, options)
    else:
        pairing = _by_file_order(shots, triggers, options)
    inside, outside = _within_log(track, pairing.taken, options, src)
    in_order = tuple(sorted(inside, key=lambda x: x[1]))
    return dataclasses.replace(pairing, taken=in_order, skipped=(*pairing.skipped, *outside))


def _within_log(
    track: LogTrack, taken: Sequence[tuple[Shot, float]], options: ImportOptions, src: str
) -> tuple[list[tuple[Shot, float]], list[tuple[str, str]]]:
    """The images within the log's time span (``--max-gap`` beyond it), and the others with
    the reason; refused when none is, saying what ``--time-offset`` did."""
    lo, hi = track.span
    tol, off = options.max_gap_s, options.offset_s
    inside = [(s, t) for s, t in taken if lo - tol <= t <= hi + tol]
    on = f"s on the log's clock, --time-offset {off:+g} s added" if off else "s"
    if taken and not inside:
        first, last = min(t for _, t in taken), max(t for _, t in taken)
        moved = ""
        if off and src == "trigger":
            moved = " (paired with camera triggers in order, the offset moves them off theirs)"
        raise InvalidInputError(
            track.source,
            f"no image falls within the log's time span ({lo:.1f} .. {hi:.1f} s; the images at "
            f"{first:.1f} .. {last:.1f} {on}){moved}: images and log of different flights, or "
            "a time offset to give (--time-offset: the seconds added to the images' times, "
            "negative when the camera's clock is ahead of the log's)",
        )
    outside = [
        (s.name, f"at {t:.1f} {on}, outside the log ({lo:.1f} .. {hi:.1f} s)")
        for s, t in taken
        if not lo - tol <= t <= hi + tol
    ]
    return inside, outside
