"""The C3-IT acceptance measures of one strategy's run over a flight with ground truth (see
:mod:`c3_matcher_tools.evaluate` for what each measures and its bar).

Every measure's ``passed`` (``"pass"`` in JSON) is True (bar met), False (bar missed) or None:
nothing to measure (its figure is n/a or 0 of 0: no true-tile frame, no matched one, no absent
frame, no frame with ground truth, no frame run twice), neither passed nor missed. A figure
judged against a bar is printed through :meth:`Bar.figure`, rounded so that the printed figure
meets the bar exactly when the measured one does."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, fields
from decimal import ROUND_CEILING, ROUND_FLOOR, Decimal
from enum import StrEnum
from typing import Any, ClassVar, Literal, cast

import numpy as np

from c3_matcher_tools.dataset.format import FrameRecord
from c3_matcher_tools.run.correct_tile_case import CorrectTileCase, correct_tile_case
from c3_matcher_tools.run.records import FrameOutcome, FrameStatus

__all__ = [
    "BARS",
    "IT01_BAR",
    "IT03_BAR",
    "IT03_BAR_PX",
    "IT04_BAR",
    "WRONG_FIX_PX",
    "AbsentRaised",
    "Acceptance",
    "Bar",
    "CorrectTile",
    "CorrectTileCase",
    "Determinism",
    "FalseConfident",
    "Headline",
    "InlierCount",
    "InlierError",
    "Measure",
    "Verdict",
    "correct_tile_case",
    "inliers_within_bound",
    "is_right_fix_other_tile",
    "is_wrong_fix",
    "it01_inliers",
    "metrics",
    "verdict",
]


@dataclass(frozen=True)
class Bar:
    """A numeric bar: a figure passes when ``figure <op> limit``."""

    op: Literal[">=", ">", "<=", "<"]
    limit: float

    def __str__(self) -> str:
        return f"{self.op} {self.limit:g}"

    def judge(self, value: float) -> bool | None:
        """Whether ``value`` meets the bar; None when there is no figure (NaN: nothing to
        measure)."""
        if not math.isfinite(value):
            return None
        return _compare(self.op, Decimal(repr(value)), Decimal(repr(self.limit)))

    def figure(self, value: float, decimals: int = 0, *, percent: bool = False) -> str:
        """``value`` printed with ``decimals`` decimals (as a percentage: ``percent``), never
        contradicting the bar: rounded as usual where the printed figure is judged as
        ``value`` is, else with as many more decimals as it takes, rounded toward the side the
        bar's limit itself is judged on (down for ``>=`` and ``<``, up for ``<=`` and ``>``):
        79.95 prints "79.9" against ``>= 80`` (not "80"), 0.946 "94.6%" against ``>= 0.95``
        (not "95%"), 2.4999 "2.499" against ``< 2.5``. "n/a" without a figure."""
        if not math.isfinite(value):
            return "n/a"
        scale = Decimal(100) if percent else Decimal(1)
        exact, limit = Decimal(repr(value)) * scale, Decimal(repr(self.limit)) * scale
        verdict = _compare(self.op, exact, limit)
        shown = Decimal(format(value * (100 if percent else 1), f".{decimals}f"))
        rounding = ROUND_FLOOR if self.op in (">=", "<") else ROUND_CEILING
        while _compare(self.op, shown, limit) != verdict and shown != exact:
            decimals += 1
            shown = exact.quantize(Decimal(1).scaleb(-decimals), rounding=rounding)
        return f"{shown:f}" + ("%" if percent else "")


def _compare(op: str, value: Decimal, limit: Decimal) -> bool:
    return {
        ">=": value >= limit,
        ">": value > limit,
        "<=": value <= limit,
        "<": value < limit,
    }[op]


IT03_BAR_PX = 2.5
IT01_BAR = Bar(">=", 80)
"""C3-IT-01: the p5 of the best candidate's inlier count."""
IT03_BAR = Bar("<", IT03_BAR_PX)
"""C3-IT-03: the p95 of the mean inlier error against ground truth (ORIGINAL frame px)."""
IT04_BAR = Bar(">=", 0.95)
"""C3-IT-04: the correct-candidate rate."""
BARS = {
    "C3-IT-01": f"{IT01_BAR} inliers (p5)",
    "C3-IT-02": "identical",
    "C3-IT-03": f"{IT03_BAR} original frame px (p95)",
    "C3-IT-04": f"{IT04_BAR}",
    "C3-IT-05": "all absent frames",
}
WRONG_FIX_PX = 4 * IT03_BAR_PX
"""A returned pick is a wrong fix when its inliers' mean error against ground truth exceeds
this (ORIGINAL frame px): four times the IT-03 bar, a scale-free bound far below any
distractor's offset (its tile centre from the true tile's, nearest per flight: 624-1062 m on
the NAIP flights, 41-132 m on zurich_z16, manila_grey_z19 and gorinchem_z18; 240 frame px or
more on every shipped flight, docs/accuracy.md) and above the per-inlier scatter of a right
but imprecise fix (IT-03 means of 2-4 px across seasons)."""


def inliers_within_bound(outcome: FrameOutcome) -> bool | None:
    """Whether a pick's inliers lie within ``WRONG_FIX_PX`` of ground truth; None where that
    is unknown (no truth homography, so no inlier error)."""
    error = outcome.mean_error_px
    return error <= WRONG_FIX_PX if math.isfinite(error) else None


def is_wrong_fix(outcome: FrameOutcome) -> bool:
    """A returned pick that places the frame wrong (see ``WRONG_FIX_PX``); a raise never is.
    An unknown inlier error counts as wrong: the measure of false confidence takes no pick on
    trust."""
    return outcome.status == FrameStatus.OK and inliers_within_bound(outcome) is not True


def is_right_fix_other_tile(outcome: FrameOutcome) -> bool:
    """A returned pick of a candidate other than the true tile whose inliers still place the
    frame right (within ``WRONG_FIX_PX``): no wrong fix, yet not the correct tile."""
    return verdict(outcome) == Verdict.OTHER_TILE


class Verdict(StrEnum):
    """What a frame's result came to, judged as eval judges it, in the report's words."""

    FAILED = "failed"
    """No pick where one was due: the match raised with its true tile a candidate (or with no
    ground truth to tell), the matcher failed, or the image could not be read."""
    RIGHTLY_RAISED = "rightly raised"
    """No pick, raised ``InsufficientInliersError`` on a frame whose true tile is not among
    its candidates: the right answer there (C3-IT-05), no failure."""
    MATCHED = "matched"
    """A pick, and no ground truth to judge it by."""
    TRUE_TILE = "true tile"
    """The true tile, its inliers within ``WRONG_FIX_PX`` of ground truth."""
    OTHER_TILE = "another tile, right fix"
    """Another candidate whose inliers still place the frame right (eval's "other tile")."""
    WRONG_TILE = "wrong tile"
    """Another candidate, placing the frame wrong: a false-confident frame."""
    TRUE_TILE_PLACED_WRONG = "true tile, placed wrong"
    """The true tile, its inliers over ``WRONG_FIX_PX`` off (or unknown): false-confident."""

    @property
    def wrong_fix(self) -> bool:
        """A pick that places the frame wrong (:func:`is_wrong_fix` of a frame with ground
        truth): what eval counts false-confident."""
        return self in (Verdict.WRONG_TILE, Verdict.TRUE_TILE_PLACED_WRONG)


def verdict(outcome: FrameOutcome) -> Verdict:
    """The frame's :class:`Verdict`: the one rule the report's table, marks and pictures, the
    run summary's counts and eval's false-confident count share."""
    if outcome.status != FrameStatus.OK:
        absent = outcome.has_truth and not outcome.true_present
        rightly = absent and outcome.status == FrameStatus.INSUFFICIENT
        rightly = rightly and not outcome.no_tile_read  # C3-IT-05's rule: the tiles were seen
        return Verdict.RIGHTLY_RAISED if rightly else Verdict.FAILED
    if not outcome.has_truth:
        return Verdict.MATCHED
    if is_wrong_fix(outcome):
        return Verdict.TRUE_TILE_PLACED_WRONG if outcome.correct else Verdict.WRONG_TILE
    return Verdict.TRUE_TILE if outcome.correct else Verdict.OTHER_TILE


def it01_inliers(outcome: FrameOutcome) -> int | None:
    """The inlier count C3-IT-01 takes from a frame: the match's, 0 when it raised; None for a
    frame it leaves out (no ground truth, its image unread, or its true tile absent)."""
    return outcome.best_inliers if outcome.scored and outcome.true_present else None


class Measure(ABC):
    """One measure (each a frozen dataclass of its figures), named ``name`` in the reports:
    ``passed`` is True (bar met), False (bar missed) or None (nothing to measure), judged from
    the figures, and written ``"pass"`` in JSON after them."""

    name: ClassVar[str]

    @property
    @abstractmethod
    def passed(self) -> bool | None: ...

    def to_json(self) -> dict[str, Any]:
        figures = {f.name: getattr(self, f.name) for f in fields(cast(Any, self))}
        return {
            **{k: list(v) if isinstance(v, tuple) else v for k, v in figures.items()},
            "pass": self.passed,
        }


@dataclass(frozen=True)
class InlierCount(Measure):
    """C3-IT-01: the p5 of the best candidate's inlier count over the true-tile frames."""

    name: ClassVar[str] = "C3-IT-01"
    p5_best_inliers: float
    frames: int

    @property
    def passed(self) -> bool | None:
        return IT01_BAR.judge(self.p5_best_inliers)


@dataclass(frozen=True)
class Determinism(Measure):
    """C3-IT-02: the frames run twice whose results differ (status or fingerprint)."""

    name: ClassVar[str] = "C3-IT-02"
    frames_compared: int
    differing_frames: tuple[int, ...]

    @property
    def passed(self) -> bool | None:
        return not self.differing_frames if self.frames_compared else None


@dataclass(frozen=True)
class InlierError(Measure):
    """C3-IT-03: the mean inlier error against ground truth of the true-tile frames matched
    (ORIGINAL frame px; p95 judged) over ``frames_scored``, and beside it the position error
    (m) of the same frames, over the ``position_error_frames`` that have one (the run
    summary's position error counts every matched frame, true tile there or not)."""

    name: ClassVar[str] = "C3-IT-03"
    p95_mean_error_px: float
    frames_scored: int
    median_mean_error_px: float
    p95_position_error_m: float
    median_position_error_m: float
    position_error_frames: int

    @property
    def passed(self) -> bool | None:
        return IT03_BAR.judge(self.p95_mean_error_px)


@dataclass(frozen=True)
class CorrectTile(Measure):
    """C3-IT-04: the true-tile frames whose best candidate is the true tile; beside the figures
    (never judged) ``case``, the case those frames are (None: not measured, no frames given)."""

    name: ClassVar[str] = "C3-IT-04"
    correct_rate: float
    correct: int
    frames: int
    case: CorrectTileCase | None = None

    @property
    def passed(self) -> bool | None:
        return IT04_BAR.judge(self.correct_rate)

    def to_json(self) -> dict[str, Any]:
        """The figures, the case's where measured (``max_tilt_deg``, ``nearest_distractor_m``,
        ``criterion_case`` and ``case`` in words) and ``"pass"``."""
        figures: dict[str, Any] = {
            "correct_rate": self.correct_rate,
            "correct": self.correct,
            "frames": self.frames,
        }
        if self.case is not None:
            figures |= {
                "max_tilt_deg": self.case.max_tilt_deg,
                "nearest_distractor_m": self.case.nearest_distractor_m,
                "criterion_case": self.case.criterion_case,
                "case": self.case.said,
            }
        return {**figures, "pass": self.passed}


@dataclass(frozen=True)
class AbsentRaised(Measure):
    """C3-IT-05: the frames without their true tile that raised ``InsufficientInliersError``:
    all of them, to pass. A frame whose every candidate was dropped for its tile
    (:attr:`~c3_matcher_tools.run.records.FrameOutcome.no_tile_read`: a damaged tile store)
    raised without the matcher seeing a tile: no evidence of a refusal, so it counts in neither
    figure (nor as a miss) but apart, in ``tiles_unread_frames``, by frame index."""

    name: ClassVar[str] = "C3-IT-05"
    insufficient: int
    absent_frames: int
    tiles_unread_frames: tuple[int, ...] = ()

    @property
    def passed(self) -> bool | None:
        return self.insufficient == self.absent_frames if self.absent_frames else None


@dataclass(frozen=True)
class FalseConfident(Measure):
    """Returned picks that are wrong fixes (:func:`is_wrong_fix`) among the frames with ground
    truth (none, to pass), and apart from them the picks of another tile that still place the
    frame right."""

    name: ClassVar[str] = "false_confident"
    frames: tuple[int, ...]
    count: int
    of: int
    rate: float
    bound_px: float
    right_fix_other_tile: tuple[int, ...]

    @property
    def passed(self) -> bool | None:
        return not self.frames if self.of else None


@dataclass(frozen=True)
class Headline:
    """The figures a strategy x flight summary row shows: correct tile of the frames whose true
    tile is present, IT-03 p95 (px), absent frames raised, and returned picks that are wrong
    fixes (false-confident) of those scored."""

    correct: int
    present: int
    it03_p95_px: float
    it05_raised: int
    absent: int
    false_confident: int
    scored: int


@dataclass(frozen=True)
class Acceptance:
    """The C3-IT measures of one strategy's run over a flight, and its false-confident picks."""

    inlier_count: InlierCount
    determinism: Determinism
    inlier_error: InlierError
    correct_tile: CorrectTile
    absent_raised: AbsentRaised
    false_confident: FalseConfident

    def measures(self) -> dict[str, Measure]:
        """Each measure (every field) by its name in the reports, in that order."""
        every: list[Measure] = [getattr(self, f.name) for f in fields(self)]
        return {m.name: m for m in every}

    def to_json(self) -> dict[str, Any]:
        """``eval.json``'s ``metrics``: each measure's figures and ``"pass"`` by its name."""
        return {name: measure.to_json() for name, measure in self.measures().items()}

    @property
    def headline(self) -> Headline:
        return Headline(
            correct=self.correct_tile.correct,
            present=self.correct_tile.frames,
            it03_p95_px=self.inlier_error.p95_mean_error_px,
            it05_raised=self.absent_raised.insufficient,
            absent=self.absent_raised.absent_frames,
            false_confident=self.false_confident.count,
            scored=self.false_confident.of,
        )


def metrics(
    run1: Sequence[FrameOutcome],
    run2: Sequence[FrameOutcome],
    frames: Sequence[FrameRecord] | None = None,
) -> Acceptance:
    """The C3-IT figures and pass flags of one strategy (see the module docstring): a flag is
    None where its measure had nothing to measure. A frame whose image could not be read is
    the camera's loss, not the matcher's: no measure counts it; nor does C3-IT-05 count a frame
    whose every candidate was dropped for its tile (:class:`AbsentRaised`). ``frames``: the
    flight's records, of which those C3-IT-04 counts give its case (:func:`correct_tile_case`;
    None: not measured)."""
    scored = [o for o in run1 if o.scored]
    present = [o for o in scored if o.true_present]
    absent = [o for o in scored if not o.true_present]
    inliers = [float(n) for o in present if (n := it01_inliers(o)) is not None]
    p5 = float(np.percentile(inliers, 5)) if inliers else math.nan
    correct = sum(o.correct for o in present)
    rate = correct / len(present) if present else math.nan
    return Acceptance(
        InlierCount(p5, len(present)),
        _it02(run1, run2),
        _it03(present),
        CorrectTile(
            rate,
            correct,
            len(present),
            None if frames is None else correct_tile_case(_records(frames, present)),
        ),
        _it05(absent),
        _false_confident(scored),
    )


def _records(frames: Sequence[FrameRecord], outcomes: Sequence[FrameOutcome]) -> list[FrameRecord]:
    """The records of ``frames`` whose outcome is among ``outcomes`` (by frame index)."""
    counted = {o.index for o in outcomes}
    return [f for f in frames if f.index in counted]


def _it02(run1: Sequence[FrameOutcome], run2: Sequence[FrameOutcome]) -> Determinism:
    """The frames the matcher ran twice (an image unreadable in either run never reached it)
    and those whose results differ."""
    first = {o.index: o for o in run1 if o.status != FrameStatus.UNREADABLE}
    compared = [o for o in run2 if o.index in first and o.status != FrameStatus.UNREADABLE]
    differing = tuple(
        o.index
        for o in compared
        if (o.status, o.fingerprint) != (first[o.index].status, first[o.index].fingerprint)
    )
    return Determinism(len(compared), differing)


def _it05(absent: Sequence[FrameOutcome]) -> AbsentRaised:
    """The absent-tile frames that raised, of those whose tiles the matcher saw; apart, those
    whose every candidate was dropped for its tile."""
    seen = [o for o in absent if not o.no_tile_read]
    raised = sum(o.status == FrameStatus.INSUFFICIENT for o in seen)
    return AbsentRaised(raised, len(seen), tuple(o.index for o in absent if o.no_tile_read))


def _it03(present: Sequence[FrameOutcome]) -> InlierError:
    positions = [o.position_error_m for o in present if o.status == FrameStatus.OK]
    positions = [p for p in positions if math.isfinite(p)]
    errors = [
        o.mean_error_px
        for o in present
        if o.status == FrameStatus.OK and math.isfinite(o.mean_error_px)
    ]
    p95 = float(np.percentile(errors, 95)) if errors else math.nan
    return InlierError(
        p95_mean_error_px=p95,
        frames_scored=len(errors),
        median_mean_error_px=float(np.median(errors)) if errors else math.nan,
        p95_position_error_m=float(np.percentile(positions, 95)) if positions else math.nan,
        median_position_error_m=float(np.median(positions)) if positions else math.nan,
        position_error_frames=len(positions),
    )


def _false_confident(scored: Sequence[FrameOutcome]) -> FalseConfident:
    wrong = tuple(o.index for o in scored if is_wrong_fix(o))
    right_elsewhere = tuple(o.index for o in scored if is_right_fix_other_tile(o))
    return FalseConfident(
        frames=wrong,
        count=len(wrong),
        of=len(scored),
        rate=len(wrong) / len(scored) if scored else math.nan,
        bound_px=WRONG_FIX_PX,
        right_fix_other_tile=right_elsewhere,
    )
