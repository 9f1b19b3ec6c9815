"""The case a flight's C3-IT-04 measured (:class:`CorrectTileCase`): the specification names
IT-04's case (attitude tilt up to +-20 deg, distractors 350 m from the true tile), not a flight;
eval measures it from the frames IT-04 counts and says where a flight is not that case."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from c3_matcher.georef import haversine_m
from c3_matcher_tools.dataset.format import FrameRecord

__all__ = [
    "IT04_DISTRACTOR_M",
    "IT04_TILT_DEG",
    "IT04_TILT_SPANNED_DEG",
    "CorrectTileCase",
    "correct_tile_case",
]

IT04_TILT_DEG = 20.0
"""C3-IT-04's case: attitude tilt up to this (deg) ..."""
IT04_DISTRACTOR_M = 350.0
"""... with distractors this far (m, or farther) from the true tile."""
IT04_TILT_SPANNED_DEG = 15.0
"""A flight spans IT-04's tilt when a frame it counts tilts this far (deg) or more: the top
quarter of the case's range, as the real-path scenarios take it (15-20 deg)."""


@dataclass(frozen=True)
class CorrectTileCase:
    """The case a flight's C3-IT-04 measured, from the frames it counts: ``max_tilt_deg``, the
    largest attitude tilt (the angle of the body's down axis from the vertical, from each
    frame's roll and pitch as the flight recorded them: ``--attitude-noise-deg`` makes what the
    matcher is given less sure, not the pictures more oblique), and ``nearest_distractor_m``,
    the nearest distractor's distance from the true tile (tile centres, great circle). NaN: no
    frame, or no distractor."""

    max_tilt_deg: float = math.nan
    nearest_distractor_m: float = math.nan

    @property
    def criterion_case(self) -> bool | None:
        """The flight spans the criterion's case: a frame tilted :data:`IT04_TILT_SPANNED_DEG`
        or more, every distractor :data:`IT04_DISTRACTOR_M` or farther; None: no frame."""
        if not math.isfinite(self.max_tilt_deg):
            return None
        far = self.nearest_distractor_m >= IT04_DISTRACTOR_M  # False for NaN: no distractor
        return self.max_tilt_deg >= IT04_TILT_SPANNED_DEG and far

    @property
    def measured(self) -> str:
        """The case in words (the tilt rounded up, the distance down: each bound holds)."""
        if self.criterion_case is None:
            return "no frame with its true tile"
        near = self.nearest_distractor_m
        far = f"distractors >= {math.floor(near)} m" if math.isfinite(near) else "no distractor"
        return f"tilt <= {self._tilt:g} deg, {far}"

    @property
    def shortfall(self) -> str | None:
        """Where the case is not the criterion's, plainly; None where it is (or no frame)."""
        if self.criterion_case is not False:
            return None
        short = []
        if self.max_tilt_deg < IT04_TILT_SPANNED_DEG:
            short.append(f"tilt up to {self._tilt:g} deg of its {IT04_TILT_DEG:g}")
        if math.isnan(self.nearest_distractor_m):
            short.append("no distractor")
        elif self.nearest_distractor_m < IT04_DISTRACTOR_M:
            short.append(f"distractors nearer than {IT04_DISTRACTOR_M:g} m")
        return "not the criterion's case: " + ", ".join(short)

    @property
    def said(self) -> str:
        """:attr:`measured`, then :attr:`shortfall` where there is one."""
        short = self.shortfall
        return self.measured if short is None else f"{self.measured}: {short}"

    @property
    def _tilt(self) -> float:
        """``max_tilt_deg`` rounded up to 0.1 deg."""
        return math.ceil(self.max_tilt_deg * 10 - 1e-9) / 10


def correct_tile_case(frames: Sequence[FrameRecord]) -> CorrectTileCase:
    """The :class:`CorrectTileCase` of ``frames``: the tilt of every one, the distractors of
    those whose true tile is among their candidates."""
    if not frames:
        return CorrectTileCase()
    tilts = [_tilt_deg(*(f.recorded_deg or f.attitude_deg)[:2]) for f in frames]
    distances = [d for f in frames for d in _distractor_distances_m(f)]
    return CorrectTileCase(max(tilts), min(distances, default=math.nan))


def _tilt_deg(roll_deg: float, pitch_deg: float) -> float:
    """The angle (deg) of the body's down axis from the vertical at ``roll_deg``, ``pitch_deg``
    (Z-Y-X): the nadir camera's tilt."""
    cos = math.cos(math.radians(roll_deg)) * math.cos(math.radians(pitch_deg))
    return math.degrees(math.acos(min(1.0, cos)))


def _distractor_distances_m(frame: FrameRecord) -> list[float]:
    """Each distractor's distance (m) from ``frame``'s true tile; none without a true tile."""
    true = frame.true_index
    if true is None:
        return []
    centre = frame.candidates[true].tile_id
    others = [c.tile_id for c in frame.candidates if c.is_true is False]
    if not others:
        return []
    lonlat = [[t.lon, t.lat] for t in others]
    return [float(d) for d in haversine_m(lonlat, [[centre.lon, centre.lat]] * len(others))]
