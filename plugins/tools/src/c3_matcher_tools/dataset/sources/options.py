"""The options of an import from a recorded log (:class:`ImportOptions`), how every import
proposes candidates (:class:`ProposalOptions`), their bounds, and what the import reports
(:class:`ImportReport`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from c3_matcher.dto import CameraCalibration, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.geo import TILE_PX
from c3_matcher_tools.dataset.format import check_candidate_size

__all__ = [
    "MAX_CANDIDATES",
    "MAX_GEOID_HEIGHT_M",
    "MAX_SEARCH_TILES",
    "MAX_TIME_OFFSET_S",
    "ImportOptions",
    "ImportReport",
    "ProposalOptions",
    "check_geoid_height",
    "check_ground_options",
    "max_uncertainty_m",
    "number_ranges",
]


MAX_SEARCH_TILES = 32
"""``--uncertainty-m`` reaches at most this many tiles of the store's zoom from the look point:
the tiles looked up per frame grow with its square (65 x 65 at most), and a few candidates never
cover more ground than that anyway."""


MAX_CANDIDATES = MAX_SEARCH_TILES**2
"""``--candidates`` proposes at most this many tiles a frame: more would not fit the square the
search reaches (:data:`MAX_SEARCH_TILES` tiles from the look point), which would widen it."""


MAX_TIME_OFFSET_S = 4e9
"""``--time-offset`` moves the images' times at most this far either way, s (127 years): enough
to put the first image on a log clock that counts UTC seconds since 1970 (an ArduPilot log's, a
ground station's: in file order the offset is that image's log time) until 2096, or to bring a
camera clock that was never set (1970, 2000) onto the log's; beyond it the times are no clock's
and the figures printed of them run to hundreds of digits."""


MAX_GROUND_ELEVATION_M = 9000.0
"""``--ground-elevation`` lies within this of sea level, m (no ground is higher or deeper)."""


def check_ground_options(ground_elevation_m: float | None, dem: Path | None) -> None:
    """The one rule of every import's ground: ``--ground-elevation`` or ``--dem``, not both
    (which would hold where the other does not is a guess; one given is used for every frame),
    and a ground elevation within :data:`MAX_GROUND_ELEVATION_M` of sea level; refused naming
    ``--ground-elevation``."""
    if ground_elevation_m is not None and dem is not None:
        raise InvalidInputError("--ground-elevation", "give it or --dem, not both")
    if ground_elevation_m is not None and not (
        math.isfinite(ground_elevation_m) and abs(ground_elevation_m) <= MAX_GROUND_ELEVATION_M
    ):
        raise InvalidInputError(
            "--ground-elevation",
            f"must be in [-{MAX_GROUND_ELEVATION_M:g}, {MAX_GROUND_ELEVATION_M:g}] m, got "
            f"{ground_elevation_m}",
        )


MAX_GEOID_HEIGHT_M = 120.0
"""``--geoid-height`` lies within this of 0, m: the geoid (sea level) lies between about 107 m
below and 86 m above the WGS84 ellipsoid (EGM2008)."""


def check_geoid_height(
    source: str, *, ellipsoidal: bool, ground_given: bool, geoid_height_m: float | None
) -> None:
    """The rule of an altitude above the WGS84 ellipsoid (a ROS bag's NavSatFix, as the message
    defines it) met by a ground above sea level (``--ground-elevation``, ``--dem``): the
    geoid height there (``--geoid-height``) must be given to bring the one to the other, else
    every height above ground is off by it (47 m at Zurich); refused
    naming ``--geoid-height`` and ``source`` (the log), saying both ways out."""
    if not (ellipsoidal and ground_given and geoid_height_m is None):
        return
    raise InvalidInputError(
        "--geoid-height",
        f"{source}: a ROS bag's NavSatFix altitude is above the WGS84 ellipsoid, and the "
        "ground (--ground-elevation, --dem) above sea level: give --geoid-height N, sea "
        "level's height above the ellipsoid at the flight, m (EGM2008; 47.4 at Zurich), or "
        "--geoid-height 0 if the bag's GNSS driver writes sea-level altitude (or the ground "
        "given is above the ellipsoid too)",
    )


def max_uncertainty_m(zoom: int, lat_deg: float = 0.0) -> float:
    """The largest ``--uncertainty-m`` at ``zoom`` and latitude ``lat_deg``: the side of
    :data:`MAX_SEARCH_TILES` web-mercator tiles there, m."""
    return MAX_SEARCH_TILES * TILE_PX * TileId(zoom, lat_deg, 0.0).web_mercator_gsd_m()


@dataclass(frozen=True, slots=True)
class ProposalOptions:
    """How candidates are proposed for each frame (:mod:`c3_matcher_tools.dataset.proposals`):
    ``candidates`` tiles of the tile store ``store`` at ``zoom`` (None: its finest), those within
    ``uncertainty_m`` (m) of the look point first, each a ``candidate_size_px`` px window, their
    order shuffled by ``seed``; ``skip_outside``: frames whose look point the store does not
    cover are skipped (else the import is refused). Refuses, naming the option, an uncertainty
    that is not finite and
    >= 0, candidates not 1 to :data:`MAX_CANDIDATES` and a candidate size out of
    :data:`~c3_matcher_tools.dataset.format.CANDIDATE_SIZE_PX`."""

    store: Path
    uncertainty_m: float = 50.0
    candidates: int = 3
    zoom: int | None = None
    candidate_size_px: int = 512
    seed: int = 0
    skip_outside: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.uncertainty_m) and self.uncertainty_m >= 0):
            raise InvalidInputError("--uncertainty-m", f"must be >= 0, got {self.uncertainty_m}")
        if not 1 <= self.candidates <= MAX_CANDIDATES:
            raise InvalidInputError(
                "--candidates", f"must be in [1, {MAX_CANDIDATES}], got {self.candidates}"
            )
        check_candidate_size(self.candidate_size_px)

    def check_store(self) -> None:
        """Refuse, naming ``STORE``, a tile store that is not a file (checked when the import
        reaches it, after the inputs it names before)."""
        store = Path(self.store)
        if store.is_dir():
            raise InvalidInputError(
                "STORE", f"{self.store}: a folder; a dataset's store is one MBTiles file"
            )
        if not store.is_file():
            raise InvalidInputError("STORE", f"{self.store}: no such tile store")

    def spec_json(self, zoom: int) -> dict[str, Any]:
        """The options as a dataset's ``spec`` records them: the store by its file name, the
        zoom the candidates were proposed at."""
        return {
            "store": Path(self.store).name,
            "uncertainty_m": self.uncertainty_m,
            "candidates": self.candidates,
            "candidate_size_px": self.candidate_size_px,
            "zoom": zoom,
            "seed": self.seed,
            "skip_outside": self.skip_outside,
        }


@dataclass(frozen=True)
class ImportOptions:
    """How images meet the log and how candidates are proposed (``proposal``; lengths m,
    times s).

    ``time_source``: ``auto`` | ``trigger`` | ``exif`` (the images' own clock) | ``order`` (file
    order, one image every ``interval_s`` from ``time_offset_s`` on the log's clock; a video's
    frames at ``time_offset_s`` plus their time in the video);
    ``time_offset_s`` is added to trigger / image times otherwise (to the images' own times when
    they state one, to the trigger times when they do not: see :func:`match_shots`); None when
    ``--time-offset`` is not given, which adds 0 (:attr:`offset_s`) but lets photos and camera
    triggers of different counts find the camera clock's offset, where a 0 given says the
    camera's clock is the log's.
    ``max_gap_s``: the farthest a log sample may be from a frame's time to be used.
    ``gnss_degraded_m``: a stated horizontal accuracy worse than this flags the frame.
    ``ground_elevation_m`` / ``dem``: the ground's altitude above sea level when the log has no
    height above ground; one or the other (:func:`check_ground_options`).
    ``geoid_height_m``: sea level's height above the WGS84 ellipsoid at the flight, which
    brings a log's altitude above the ellipsoid (a ROS bag's NavSatFix) to sea level before
    the ground is taken from it (:func:`check_geoid_height`); within
    :data:`MAX_GEOID_HEIGHT_M`."""

    calibration: CameraCalibration
    proposal: ProposalOptions
    time_source: str = "auto"
    time_offset_s: float | None = None
    interval_s: float | None = None
    max_gap_s: float = 1.0
    gnss_degraded_m: float = 5.0
    ground_elevation_m: float | None = None
    dem: Path | None = None
    geoid_height_m: float | None = None

    def __post_init__(self) -> None:
        if self.time_source not in ("auto", "trigger", "exif", "order"):
            raise InvalidInputError(
                "--time-source", f"one of auto, trigger, exif, order; got {self.time_source!r}"
            )
        if not (math.isfinite(self.offset_s) and abs(self.offset_s) <= MAX_TIME_OFFSET_S):
            raise InvalidInputError(
                "--time-offset",
                f"must be in [-{MAX_TIME_OFFSET_S:g}, {MAX_TIME_OFFSET_S:g}] s, got "
                f"{self.offset_s:g}",
            )
        if self.interval_s is not None and not (
            math.isfinite(self.interval_s) and self.interval_s > 0
        ):
            raise InvalidInputError("--interval", f"must be > 0 s, got {self.interval_s}")
        if not (math.isfinite(self.max_gap_s) and self.max_gap_s > 0):
            raise InvalidInputError("--max-gap", f"must be > 0 s, got {self.max_gap_s}")
        if not (math.isfinite(self.gnss_degraded_m) and self.gnss_degraded_m > 0):
            raise InvalidInputError(
                "--gnss-degraded-m", f"must be > 0 m, got {self.gnss_degraded_m}"
            )
        check_ground_options(self.ground_elevation_m, self.dem)
        geoid = self.geoid_height_m
        if geoid is not None and not (math.isfinite(geoid) and abs(geoid) <= MAX_GEOID_HEIGHT_M):
            raise InvalidInputError(
                "--geoid-height",
                f"must be in [-{MAX_GEOID_HEIGHT_M:g}, {MAX_GEOID_HEIGHT_M:g}] m, got {geoid}",
            )

    @property
    def offset_s(self) -> float:
        """The seconds added to the images' times: ``time_offset_s``, 0 when it is not given
        (what the import reports and its dataset records either way)."""
        return 0.0 if self.time_offset_s is None else self.time_offset_s


@dataclass(frozen=True)
class ImportReport:
    """What an import did: frames taken, skipped (image, reason), how times were matched, the
    height source per frame and the marked frames; :meth:`lines` reads it to a person.
    ``time_offset_s`` is the offset added to the images' times and ``time_offset_origin`` says
    where it came from: ``found`` (the camera clock's, from the photos and the camera
    triggers), ``given`` (``--time-offset``) or ``not given`` (0)."""

    dataset: str
    source: str
    kind: str
    frames: int
    skipped: tuple[tuple[str, str], ...]
    time_source: str
    time_offset_s: float
    height_sources: dict[str, int]
    attitude_assumed: tuple[int, ...]
    height_assumed: tuple[int, ...]
    gnss_degraded: tuple[int, ...]
    zoom: int
    notes: tuple[str, ...] = ()
    time_offset_origin: str = "not given"

    def to_json(self) -> dict[str, Any]:
        """Every field, in order, JSON-ready: a skipped image as {"image", "reason"}."""
        return {**asdict(self), "skipped": [{"image": n, "reason": r} for n, r in self.skipped]}

    @classmethod
    def from_record(cls, record: dict[str, Any], dataset: str) -> ImportReport:
        """The report a dataset keeps of its import (``dataset.json``'s ``import``: every field
        of :meth:`to_json` but the dataset's own name, given here; a record from before the
        offset's origin was recorded: ``given`` where the offset is not 0)."""
        offset = float(record["time_offset_s"])
        return cls(
            dataset=dataset,
            source=str(record["source"]),
            kind=str(record["kind"]),
            frames=int(record["frames"]),
            skipped=tuple((str(s["image"]), str(s["reason"])) for s in record["skipped"]),
            time_source=str(record["time_source"]),
            time_offset_s=offset,
            height_sources={str(k): int(v) for k, v in record["height_sources"].items()},
            attitude_assumed=tuple(int(i) for i in record["attitude_assumed"]),
            height_assumed=tuple(int(i) for i in record["height_assumed"]),
            gnss_degraded=tuple(int(i) for i in record["gnss_degraded"]),
            zoom=int(record["zoom"]),
            notes=tuple(str(n) for n in record.get("notes", ())),
            time_offset_origin=str(
                record.get("time_offset_origin", "given" if offset else "not given")
            ),
        )

    def lines(self) -> list[str]:
        heights = ", ".join(f"{k} ({v})" for k, v in sorted(self.height_sources.items()))
        out = [
            f"imported {self.frames} frame(s) from {self.source} ({self.kind}) into {self.dataset}",
            f"  times: {self.time_source}, offset {self.time_offset_s:+.3f} s "
            f"({self.time_offset_origin})",
            f"  height above ground: {heights or 'none'}",
        ]
        for what, frames in (
            ("attitude assumed level (no attitude sample)", self.attitude_assumed),
            ("height taken from the nearest frame (no height)", self.height_assumed),
            ("GNSS absent or degraded", self.gnss_degraded),
        ):
            if frames:
                out.append(f"  {what}: frames {number_ranges(frames)}")
        if not self.skipped:
            out.append("  skipped: none")
        else:
            out.append(f"  skipped {len(self.skipped)} image(s):")
            out.extend(f"    {n}: {r}" for n, r in self.skipped[:20])
            if len(self.skipped) > 20:
                out.append(f"    (+{len(self.skipped) - 20} more)")
        out.extend(f"  note: {n}" for n in self.notes)
        return out


def number_ranges(values: Sequence[int]) -> str:
    """``[1, 2, 3, 7]`` -> ``"1-3, 7"``."""
    parts: list[list[int]] = []
    for v in sorted(values):
        if parts and parts[-1][1] == v - 1:
            parts[-1][1] = v
        else:
            parts.append([v, v])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in parts)
