"""The camera clock's offset from the log's, found from the photos' own times and the log's
camera triggers (:func:`fit_camera_clock`): one number for the whole flight, the one that pairs
the most photos with a trigger.

Why not pair each photo with the trigger nearest its own time: the triggers come at a steady
interval, so a camera clock off by any amount puts every photo within half an interval of SOME
trigger, that of a photo one or more triggers away. Only the offset that pairs the most photos
tells them apart: shifted by whole trigger intervals, the photos run off the triggers at one end
(images without a trigger there, triggers without an image at the other end, the signature of a
shift), so each such shift pairs fewer. Where a shift pairs as many (a trigger lost at either
end, the photos all there), the differences' spread tells them apart where the triggers' own
timing does (:data:`TIGHTER`), else the offsets are a tie and the import is refused."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from c3_matcher.arrays import F64
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.sources.track import LogTrack, Shot

__all__ = [
    "TIGHTER",
    "ClockFit",
    "fit_camera_clock",
    "found_offset",
    "nearest_triggers",
    "shot_names",
]

_MAX_LOOKS = 64
"""Pairs of bins looked into at most. A flight's offsets by whole trigger intervals fill a few
(the best and the shifts by one interval either way, each over two or three bins); where more
than this could pair about as many as the best, the photos' times follow no one offset of the
triggers' (another flight's photos), and the fit says another offset may pair as many.
"""

TIGHTER = 4.0
"""How many times smaller the spread of one offset's photo-trigger differences must be than
another's pairing as many for it to win: at the camera clock's true offset the differences
spread only as the photos' time stamps are coarse and the exposure follows the trigger unevenly;
shifted by whole trigger intervals they spread as that plus the unevenness of the intervals
themselves (each photo meets a neighbour's trigger). So where the triggers' timing varies
clearly more than the stamps (times to the millisecond, triggers a few milliseconds uneven or
more), the true offset's spread is the smaller by far; where it does not (whole-second EXIF
times, triggers of a steady timer), the spreads are alike and nothing tells the offsets apart.
The factor is well beyond what the spread (a median absolute deviation) varies by between
two samples of a handful of pairs of one timing, so a tie is broken only by timing that
differs, whatever the flight."""

_STAMP_S = 0.001
"""The finest spread of photo-trigger differences counted, s: the millisecond a photo's time
stamp states at best (EXIF ``SubSecTime``), below which spreads are not told apart."""

_CHUNK = 1_000_000
"""Photo-trigger differences counted at a time: the memory of the count stays a few MB however
long the flight (its time grows with photos x triggers, about a second for 10,000 x 10,000)."""


@dataclass(frozen=True, slots=True)
class ClockFit:
    """The camera clock's offset (``offset_s``, added to the photos' own times; negative when
    the camera's clock is ahead of the log's), how many photos it pairs with a trigger
    (``paired``), the spread of its photo-trigger differences (``spread_s``: their median
    absolute deviation, at least a millisecond), and the best offset apart from it with its
    count (``runner_up``; None when no other offset pairs any) and spread
    (``runner_up_spread_s``; nan when not known)."""

    offset_s: float
    paired: int
    runner_up: tuple[float, int] | None
    spread_s: float = _STAMP_S
    runner_up_spread_s: float = math.nan

    @property
    def tied(self) -> bool:
        """Whether the runner-up pairs as many and the best's spread is not clearly
        (:data:`TIGHTER`) smaller than its: the offsets are not told apart."""
        if self.runner_up is None or self.runner_up[1] < self.paired:
            return False
        return not self.spread_s * TIGHTER <= self.runner_up_spread_s


def fit_camera_clock(own: F64, triggers: F64, width_s: float) -> ClockFit | None:
    """The offset that, added to the photos' ``own`` times, pairs the most photos one-to-one
    with ``triggers`` (ascending) within a window ``width_s`` wide, and the best offset apart
    from it (more than ``width_s`` away); None when no photo meets a trigger at any offset.

    The window holds every photo's difference to its trigger when it is as wide as the spread
    of those differences (whole-second EXIF times spread them over 1 s; the time between a
    trigger and the exposure adds milliseconds) and at most half the triggers' interval, so
    that no window holds the differences of two shifts by a whole interval: the caller's
    tolerance (:func:`c3_matcher_tools.dataset.sources.pairing._tolerance`) is both. The offset
    is the median of the differences the window holds. Every difference of a photo and a
    trigger is a candidate, so no offset is assumed (a camera clock off by hours is found
    alike); counted in bins ``width_s`` wide, the windows are searched from the fullest pair
    of neighbouring bins (every window lies in two, so a pair's count bounds its windows') down,
    until no pair could hold one fewer than the best or as many as the best found apart from
    it (the next best is said beside the best), at most :data:`_MAX_LOOKS` pairs. Of offsets
    pairing as many, the one whose differences spread the least is the best, and a tie
    (:attr:`ClockFit.tied`) unless that spread is clearly the smaller (:data:`TIGHTER`)."""
    if not own.size or not triggers.size:
        return None
    lo = float(triggers[0] - own.max())
    keys, counts = _bin_counts(own, triggers, lo, width_s)
    nxt = np.zeros_like(counts)
    follows = keys[1:] == keys[:-1] + 1
    nxt[:-1][follows] = counts[1:][follows]
    bound = counts + nxt  # at most as many pairs in any window starting in that bin
    found: list[_Window] = []
    for n, b in enumerate(np.argsort(-bound, kind="stable")):
        enough = max(_top(found).paired - 1, _rival(found, width_s).paired) if found else 0
        if bound[b] < max(enough, 1):
            break
        start = lo + float(keys[b]) * width_s
        if n == _MAX_LOOKS:  # as many may lie here as at the best: not told apart
            found.append(_Window(_top(found).paired if found else 0, start + width_s, math.nan))
            break
        best = _best_window(own, triggers, start, start + 2 * width_s, width_s)
        if best is not None:
            found.append(best)
    if not found:
        return None
    top, second = _top(found), _rival(found, width_s)
    runner_up = (second.offset_s, second.paired) if second.paired else None
    return ClockFit(top.offset_s, top.paired, runner_up, top.spread_s, second.spread_s)


@dataclass(frozen=True, slots=True)
class _Window:
    """A window of photo-trigger differences: the photos it pairs, the median of its
    differences (the offset) and their spread (nan where not looked into)."""

    paired: int
    offset_s: float
    spread_s: float


def _top(found: list[_Window]) -> _Window:
    """Of ``found``, the one pairing the most, of those the one spreading the least (an unknown
    spread the most), of those the first: deterministic."""
    spread = [w.spread_s if math.isfinite(w.spread_s) else math.inf for w in found]
    return found[min(range(len(found)), key=lambda i: (-found[i].paired, spread[i], i))]


def _rival(found: list[_Window], width_s: float) -> _Window:
    """The best of ``found`` more than ``width_s`` from :func:`_top` (an unknown spread taken
    as the hardest to beat); one pairing none when there is none."""
    top = _top(found)
    apart = [w for w in found if abs(w.offset_s - top.offset_s) > width_s]
    if not apart:
        return _Window(0, math.nan, math.nan)
    spread = [w.spread_s if math.isfinite(w.spread_s) else -math.inf for w in apart]
    return apart[min(range(len(apart)), key=lambda i: (-apart[i].paired, spread[i], i))]


def _spread(diff: F64) -> float:
    """The spread of photo-trigger differences: their median absolute deviation, at least
    :data:`_STAMP_S`."""
    return max(float(np.median(np.abs(diff - np.median(diff)))), _STAMP_S)


def _bin_counts(own: F64, triggers: F64, lo: float, width_s: float) -> tuple[F64, F64]:
    """How many photo-trigger differences (trigger minus photo time) fall in each bin
    ``width_s`` wide from ``lo``: the bins that hold any, ascending, and their counts (only
    those: a photo whose clock was reset to 1970 spreads the differences over decades)."""
    rows = max(1, _CHUNK // triggers.size)
    keys: list[np.ndarray] = []
    counts: list[np.ndarray] = []
    for at in range(0, own.size, rows):
        diff = triggers[None, :] - own[at : at + rows, None]
        k, c = np.unique(np.floor((diff - lo) / width_s).astype(np.int64), return_counts=True)
        keys.append(k)
        counts.append(c)
    every, where = np.unique(np.concatenate(keys), return_inverse=True)
    return every.astype(np.float64), np.bincount(where, np.concatenate(counts)).astype(np.float64)


def _best_window(own: F64, triggers: F64, a: float, b: float, width_s: float) -> _Window | None:
    """Of the windows ``width_s`` wide among the photo-trigger differences in [``a``, ``b``),
    the one pairing the most photos one-to-one (the fewer of the photos and triggers it
    holds: a stray photo or a double trigger beside a pair adds none), with the median of its
    differences and their spread; None when none lies there."""
    first = np.searchsorted(triggers, own + a, side="left")
    last = np.searchsorted(triggers, own + b, side="left")
    many = last - first
    if not many.sum():
        return None
    photo = np.repeat(np.arange(own.size), many)
    trig = np.arange(int(many.sum())) - np.repeat(np.cumsum(many) - many, many)
    trig = trig + np.repeat(first, many)
    diff = triggers[trig] - own[photo]
    order = np.lexsort((trig, photo, diff))
    diff, photo, trig = diff[order], photo[order], trig[order]
    ends = np.searchsorted(diff, diff + width_s, side="right")
    best: _Window | None = None
    for s in np.argsort(-(ends - np.arange(diff.size)), kind="stable"):
        e = int(ends[s])
        if best is not None and e - s <= best.paired:
            break  # no later window holds more differences than this pairs
        paired = min(np.unique(photo[s:e]).size, np.unique(trig[s:e]).size)
        if best is None or paired > best.paired:
            best = _Window(paired, float(np.median(diff[s:e])), _spread(diff[s:e]))
    return best


def shot_names(shots: Sequence[Shot], shown: int = 3) -> str:
    """The first ``shown`` shots' names, then how many more."""
    more = f" and {len(shots) - shown} more" if len(shots) > shown else ""
    return ", ".join(s.name for s in shots[:shown]) + more


def nearest_triggers(
    shots: Sequence[Shot], own: Sequence[float], triggers: F64, tol: float
) -> tuple[list[tuple[Shot, float]], list[tuple[str, str]]]:
    """Each image paired with the camera trigger nearest its ``own`` time, each trigger used
    once (by the image nearest it), at the trigger's time; an image farther than ``tol`` from
    every trigger, or whose trigger is nearer another image's time, is left unpaired with the
    reason."""
    nearest = [int(np.argmin(np.abs(triggers - t))) for t in own]
    gaps = [abs(float(triggers[j]) - t) for j, t in zip(nearest, own, strict=True)]
    owner: dict[int, int] = {}  # trigger -> the image nearest it in time
    for k, (j, d) in enumerate(zip(nearest, gaps, strict=True)):
        if d <= tol and (j not in owner or d < gaps[owner[j]]):
            owner[j] = k
    taken: list[tuple[Shot, float]] = []
    skipped: list[tuple[str, str]] = []
    for k, (shot, t, j, d) in enumerate(zip(shots, own, nearest, gaps, strict=True)):
        at = float(triggers[j])
        if d > tol:
            why = (
                f"no camera trigger within {tol:g} s of its own time ({t:.2f} s on the "
                f"log's clock; the nearest at {at:.2f} s)"
            )
            skipped.append((shot.name, why))
        elif owner[j] != k:
            why = f"its nearest camera trigger ({at:.2f} s) is nearer the time of "
            skipped.append((shot.name, why + shots[owner[j]].name))
        else:
            taken.append((shot, at))
    return taken, skipped


def found_offset(
    track: LogTrack, shots: Sequence[Shot], triggers: F64, own: Sequence[float], tol: float
) -> tuple[float, str]:
    """The camera clock's offset from the log's (:func:`fit_camera_clock`, within a window
    ``tol`` wide) and what ``how`` says of it; refused, naming the offsets and
    ``--time-offset``, when it is not one number the photos agree on: fewer than half of the
    photos or triggers (the fewer) pair at the best (a clock that jumped in flight, another
    flight's photos: one offset would pair nearly all), another offset apart from it pairs as
    many and its differences spread alike (:attr:`ClockFit.tied`: whole trigger intervals
    apart, photos and triggers lost at the ends look alike: each named with what it pairs, as
    the ``--time-offset`` to give: 0 for the camera's clock), or
    no photo's own time lies within the triggers' span (their times then do not show them to
    be of this flight: a camera clock hours off is named, and given, used)."""
    fit = fit_camera_clock(np.asarray(own, dtype=np.float64), triggers, tol)
    assert fit is not None  # every photo-trigger difference lies in some window
    head = f"{track.source}: {triggers.size} camera trigger(s) in the log but {len(shots)} image(s)"
    way = "give the camera clock's offset with --time-offset (the seconds added to the images' "
    way += "own times; one given is used as given, and 0 says the camera's clock is the log's)"
    at = f"{fit.offset_s:+.2f} s (added to the images' own times)"
    if fit.runner_up is not None and fit.tied:
        other = fit.runner_up[0]
        drop = (
            "remove the images left without a trigger at the right one (as many photos as "
            "triggers meet them in capture order), or "
            if len(shots) > triggers.size
            else ""
        )
        each = " or ".join(
            f"--time-offset {_offset_word(d)} ({_what_pairs(shots, own, triggers, tol, d)})"
            for d in sorted((fit.offset_s, other), key=abs)  # no offset first
        )
        raise InvalidInputError(
            "--time-source",
            f"{head}, and the camera clock's offset is not told by them: {at} and "
            f"{other:+.2f} s each pair {fit.paired} image(s) with a trigger{_spreads(fit)}: "
            "whole trigger intervals apart, images lost at one end look like triggers lost at "
            "the other; "
            f"{drop}give the one that is right, {each}",
        )
    lo, hi = float(triggers[0]) - tol, float(triggers[-1]) + tol
    off_flight = not any(lo <= t <= hi for t in own)
    if 2 * fit.paired < min(len(shots), triggers.size) or off_flight:
        why = (
            f"none of the images' own times lies within the triggers' span ({lo:.1f} .. "
            f"{hi:.1f} s on the log's clock): their times do not show them to be of this "
            "flight (images of another flight, or a camera clock that far off?)"
            if off_flight
            else "that is fewer than half of them: no one clock offset pairs them within "
            f"{tol:g} s (a camera clock that jumped in flight, images of another flight, or "
            "--max-gap narrower than the spread of the images' times: 1 s for whole-second "
            "EXIF times?)"
        )
        raise InvalidInputError(
            "--time-source",
            f"{head}; the camera clock's offset that pairs the most images with a trigger, "
            f"{at}, pairs {fit.paired}, and {why}: {way}",
        )
    return fit.offset_s, _offset_said(fit)


def _offset_said(fit: ClockFit) -> str:
    """``"the images' times moved -4.00 s (the camera's clock 4.00 s ahead of the log's, found:
    that offset pairs 9 of them, the next best, -2.00 s, 8)"``."""
    off = fit.offset_s
    clock = "on the log's" if abs(off) < 0.005 else f"{abs(off):.2f} s "
    clock += "" if abs(off) < 0.005 else ("ahead of the log's" if off < 0 else "behind the log's")
    best = f"that offset pairs {fit.paired} of them"
    if fit.runner_up is not None:
        best += f", the next best, {fit.runner_up[0]:+.2f} s, {fit.runner_up[1]}"
        best += _spreads(fit) if fit.runner_up[1] >= fit.paired else ""
    return f"the images' times moved {off:+.2f} s (the camera's clock {clock}, found: {best})"


def _spreads(fit: ClockFit) -> str:
    """``" (the photo-trigger differences spread 1.0 ms at -4.00 s, 52.3 ms at -2.00 s)"``:
    the spreads (median absolute deviations) that break a tie of counts, or fail to; empty when
    the next best's is not known."""
    if fit.runner_up is None or not math.isfinite(fit.runner_up_spread_s):
        return ""
    return (
        f" (the photo-trigger differences spread {fit.spread_s * 1000:.1f} ms at "
        f"{fit.offset_s:+.2f} s, {fit.runner_up_spread_s * 1000:.1f} ms at "
        f"{fit.runner_up[0]:+.2f} s)"
    )


def _offset_word(offset: float) -> str:
    """``offset`` as ``--time-offset`` takes it, to the hundredth of a second the refusals
    state: ``-2.0`` -> ``"-2"``, ``0.001`` -> ``"0"``."""
    word = f"{offset:.2f}".rstrip("0").rstrip(".")
    return "0" if word == "-0" else word


def _what_pairs(
    shots: Sequence[Shot], own: Sequence[float], triggers: F64, tol: float, offset: float
) -> str:
    """``"pairs DJI_0001.JPG at the trigger at 102.0 s .. DJI_0004.JPG at 108.0 s, leaving the
    trigger(s) at 100.0 s without an image"``: the first and last pairs at ``offset`` (in
    trigger order) and what is left unpaired."""
    taken, _ = nearest_triggers(shots, [t + offset for t in own], triggers, tol)
    taken.sort(key=lambda pair: pair[1])
    pairs = f"pairs {taken[0][0].name} at the trigger at {taken[0][1]:.1f} s" if taken else ""
    pairs += f" .. {taken[-1][0].name} at {taken[-1][1]:.1f} s" if len(taken) > 1 else ""
    kept, used = {id(s) for s, _ in taken}, {t for _, t in taken}
    alone = [s for s in shots if id(s) not in kept]
    parts = [f"{shot_names(alone)} without a trigger"] if alone else []
    idle = [f"{t:.1f}" for t in triggers.tolist() if t not in used]
    more = f" and {len(idle) - 3} more" if len(idle) > 3 else ""
    parts += [f"the trigger(s) at {', '.join(idle[:3])}{more} s without an image"] if idle else []
    return ", leaving ".join(filter(None, (pairs, " and ".join(parts)))) or "pairs none"
