"""What every recorded-log importer shares: time series read from a log, images matched to the
log's clock, per-frame telemetry (position, attitude, height above ground, GNSS quality) and the
``c3-flight/1`` dataset written from them.

Conventions: times in seconds on the log's own clock (``t_s``); ``utc_offset_s`` turns it into
UTC (``utc = t_s + utc_offset_s``) when the log says; attitude in degrees, aerospace Z-Y-X
(yaw, pitch, roll) of the BODY in NED, yaw from true north clockwise; latitude/longitude WGS84
degrees; ``alt_m`` above mean sea level (or the ellipsoid, as the log states it); heights in
metres above the ground.

A frame whose time finds no attitude sample is imported level with the yaw of the GNSS course
(flag ``attitude_assumed``); one without a height above ground gets the nearest frame's height
(flag ``height_assumed``); one whose GNSS is absent, without a 3D fix, or less accurate than the
degraded bound is flagged ``gnss_degraded`` (its position comes from the estimator when the log
has one). Frames without any position are skipped with their reason: no candidate can be
proposed for them.
"""

from __future__ import annotations

import importlib
import math
import shutil
import uuid
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.arrays import F64
from c3_matcher.camera import body_from_camera
from c3_matcher.dto import CameraCalibration, TileId
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.geo import TILE_PX
from c3_matcher_tools.dataset.atomic import atomic_directory, check_output_dir
from c3_matcher_tools.dataset.format import check_candidate_size, write_dataset

__all__ = [
    "MAX_CANDIDATES",
    "MAX_SEARCH_TILES",
    "ImportOptions",
    "ImportReport",
    "LogTrack",
    "Series",
    "Shot",
    "assemble_frames",
    "attitude_from_matrix",
    "body_attitude_for_camera",
    "check_proposal_options",
    "ground_elevation_sampler",
    "image_problem",
    "logs_library",
    "match_shots",
    "max_uncertainty_m",
    "write_imported_flight",
]


def logs_library(module: str, path: Path, reading: str) -> Any:
    """``module``, a library of the logs extra, imported to read ``path`` (``reading``: what it
    is); refused naming the extra when it is not installed."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise InvalidInputError(
            str(path),
            f"reading {reading} needs the logs extra: pip install 'c3-matcher-tools[logs]'",
        ) from None


@dataclass(frozen=True)
class Series:
    """Samples of one log quantity: ``t_s`` (n,) ascending seconds on the log's clock,
    ``values`` (n, k), NaN where a sample lacks a value; columns listed in ``angles`` are
    degrees and interpolated the short way round. ``name``: the topic / message it came from."""

    name: str
    t_s: F64
    values: F64
    angles: tuple[int, ...] = ()

    @classmethod
    def build(
        cls,
        name: str,
        t_s: Sequence[float] | F64,
        values: Sequence[Sequence[float]] | F64,
        angles: tuple[int, ...] = (),
        *,
        source: str,
    ) -> Series:
        """Check the samples (finite times that never step back) and keep the finite rows;
        raises InvalidInputError naming ``source`` and the topic at a backward time jump."""
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        v = np.asarray(values, dtype=np.float64).reshape(t.size, -1)
        steps = np.diff(t)
        back = np.flatnonzero(steps < 0)
        if back.size:
            i = int(back[0])
            raise InvalidInputError(
                source,
                f"time jumps back {-steps[i]:.3f} s at {t[i]:.3f} s in {name} (a log cut and "
                "joined, or two logs in one?)",
            )
        keep = np.isfinite(t) & np.any(np.isfinite(v), axis=1)
        v = v[keep].copy()
        for col in angles:
            ok = np.isfinite(v[:, col])
            v[ok, col] = np.degrees(np.unwrap(np.radians(v[ok, col])))
        return cls(name, t[keep], v, angles)

    def __len__(self) -> int:
        return int(self.t_s.size)

    @property
    def span(self) -> tuple[float, float]:
        return (float(self.t_s[0]), float(self.t_s[-1])) if len(self) else (math.nan, math.nan)

    def at(self, t: float, max_gap_s: float) -> F64 | None:
        """Linear interpolation at ``t`` between the samples around it when both are within
        ``max_gap_s``, else the nearer one when it is within ``max_gap_s``; None otherwise."""
        if not len(self):
            return None
        j = int(np.searchsorted(self.t_s, t))
        lo, hi = max(j - 1, 0), min(j, len(self) - 1)
        dlo, dhi = abs(t - self.t_s[lo]), abs(self.t_s[hi] - t)
        if lo != hi and dlo <= max_gap_s and dhi <= max_gap_s and self.t_s[hi] > self.t_s[lo]:
            w = (t - self.t_s[lo]) / (self.t_s[hi] - self.t_s[lo])
            out = (1 - w) * self.values[lo] + w * self.values[hi]
        elif min(dlo, dhi) <= max_gap_s:
            out = self.values[lo if dlo <= dhi else hi].copy()
        else:
            return None
        for col in self.angles:
            out[col] = (out[col] + 180.0) % 360.0 - 180.0
        return np.asarray(out, dtype=np.float64)


@dataclass(frozen=True)
class LogTrack:
    """What a log says about the vehicle. ``attitude``: roll, pitch, yaw (deg, body);
    ``position``: lat, lon, alt_m; ``gnss``: the receiver's own lat, lon, alt_m, horizontal
    accuracy (m, NaN when not stated) and fix type (3 = 3D); ``height``: height above ground
    (m, valid samples only, e.g. a rangefinder); ``triggers_s``: camera trigger times;
    ``home_alt_m``: the ground's altitude at home (same datum as ``alt_m``)."""

    source: str
    kind: str
    attitude: Series | None
    position: Series | None
    gnss: Series | None = None
    height: Series | None = None
    triggers_s: F64 | None = None
    home_alt_m: float | None = None
    utc_offset_s: float | None = None
    notes: tuple[str, ...] = ()
    per_image: bool = False
    """Each image states its own position (photo metadata): it is used as the GNSS fix."""
    damage: str | None = None
    """What the log's reader said of a damaged or truncated log (read up to the damage)."""

    @property
    def span(self) -> tuple[float, float]:
        """First and last time of the position (or GNSS) samples."""
        pos = self.position if self.position is not None and len(self.position) else self.gnss
        return pos.span if pos is not None else (math.nan, math.nan)


@dataclass(frozen=True)
class Shot:
    """One image: ``name`` (as the user knows it), ``read`` returns its encoded bytes,
    ``suffix`` its file suffix, ``t_s`` its own clock (UTC seconds for EXIF / bag stamps) when
    known; ``own`` carries what the image itself records (EXIF position, gimbal angles...)."""

    name: str
    read: Callable[[], bytes]
    suffix: str = ".jpg"
    t_s: float | None = None
    own: dict[str, Any] = field(default_factory=dict)


def constant(data: bytes) -> Callable[[], bytes]:
    """A :attr:`Shot.read` for bytes already in memory."""
    return lambda: data


MAX_SEARCH_TILES = 32
"""``--uncertainty-m`` reaches at most this many tiles of the store's zoom from the look point:
the tiles looked up per frame grow with its square (65 x 65 at most), and a few candidates never
cover more ground than that anyway."""


MAX_CANDIDATES = MAX_SEARCH_TILES**2
"""``--candidates`` proposes at most this many tiles a frame: more would not fit the square the
search reaches (:data:`MAX_SEARCH_TILES` tiles from the look point), which would widen it."""


def max_uncertainty_m(zoom: int, lat_deg: float = 0.0) -> float:
    """The largest ``--uncertainty-m`` at ``zoom`` and latitude ``lat_deg``: the side of
    :data:`MAX_SEARCH_TILES` web-mercator tiles there, m."""
    return MAX_SEARCH_TILES * TILE_PX * TileId(zoom, lat_deg, 0.0).web_mercator_gsd_m()


def check_proposal_options(uncertainty_m: float, candidates: int, candidate_size_px: int) -> None:
    """``InvalidInputError`` naming the option unless the look-point uncertainty (m) is finite
    and >= 0, 1 to :data:`MAX_CANDIDATES` candidates are asked for and the candidate size is in
    :data:`~c3_matcher_tools.dataset.format.CANDIDATE_SIZE_PX`."""
    if not (math.isfinite(uncertainty_m) and uncertainty_m >= 0):
        raise InvalidInputError("--uncertainty-m", f"must be >= 0, got {uncertainty_m}")
    if not 1 <= candidates <= MAX_CANDIDATES:
        raise InvalidInputError(
            "--candidates", f"must be in [1, {MAX_CANDIDATES}], got {candidates}"
        )
    check_candidate_size(candidate_size_px)


@dataclass(frozen=True)
class ImportOptions:
    """How images meet the log and how candidates are proposed (lengths m, times s).

    ``time_source``: ``auto`` | ``trigger`` | ``exif`` (the images' own clock) | ``order`` (file
    order, one image every ``interval_s`` from ``time_offset_s`` on the log's clock; a video's
    frames at ``time_offset_s`` plus their time in the video);
    ``time_offset_s`` is added to trigger / image times otherwise (to the images' own times when
    they are paired with triggers by time: see :func:`match_shots`). ``max_gap_s``: the farthest a
    log sample may be from a frame's time to be used. ``gnss_degraded_m``: a stated horizontal
    accuracy worse than this flags the frame. ``ground_elevation_m`` / ``dem``: the ground's
    altitude (same datum as the log's altitude) when the log has no height above ground."""

    calibration: CameraCalibration
    store: Path
    time_source: str = "auto"
    time_offset_s: float = 0.0
    interval_s: float | None = None
    max_gap_s: float = 1.0
    gnss_degraded_m: float = 5.0
    ground_elevation_m: float | None = None
    dem: Path | None = None
    uncertainty_m: float = 50.0
    candidates: int = 3
    zoom: int | None = None
    candidate_size_px: int = 512
    seed: int = 0

    def __post_init__(self) -> None:
        if self.time_source not in ("auto", "trigger", "exif", "order"):
            raise InvalidInputError(
                "--time-source", f"one of auto, trigger, exif, order; got {self.time_source!r}"
            )
        if not (math.isfinite(self.time_offset_s)):
            raise InvalidInputError("--time-offset", f"must be finite, got {self.time_offset_s}")
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
        if self.ground_elevation_m is not None and not math.isfinite(self.ground_elevation_m):
            raise InvalidInputError("--ground-elevation", "must be finite")
        check_proposal_options(self.uncertainty_m, self.candidates, self.candidate_size_px)


@dataclass(frozen=True)
class ImportReport:
    """What an import did: frames taken, skipped (image, reason), how times were matched, the
    height source per frame and the marked frames; :meth:`lines` reads it to a person."""

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

    def to_json(self) -> dict[str, Any]:
        """Every field, in order, JSON-ready: a skipped image as {"image", "reason"}."""
        return {**asdict(self), "skipped": [{"image": n, "reason": r} for n, r in self.skipped]}

    def lines(self) -> list[str]:
        heights = ", ".join(f"{k} ({v})" for k, v in sorted(self.height_sources.items()))
        out = [
            f"imported {self.frames} frame(s) from {self.source} ({self.kind}) into {self.dataset}",
            f"  times: {self.time_source}, offset {self.time_offset_s:+.3f} s",
            f"  height above ground: {heights or 'none'}",
        ]
        for what, frames in (
            ("attitude assumed level (no attitude sample)", self.attitude_assumed),
            ("height taken from the nearest frame (no height)", self.height_assumed),
            ("GNSS absent or degraded", self.gnss_degraded),
        ):
            if frames:
                out.append(f"  {what}: frames {_ranges(frames)}")
        if not self.skipped:
            out.append("  skipped: none")
        else:
            out.append(f"  skipped {len(self.skipped)} image(s):")
            out.extend(f"    {n}: {r}" for n, r in self.skipped[:20])
            if len(self.skipped) > 20:
                out.append(f"    (+{len(self.skipped) - 20} more)")
        out.extend(f"  note: {n}" for n in self.notes)
        return out


def _ranges(values: Sequence[int]) -> str:
    """``[1, 2, 3, 7]`` -> ``"1-3, 7"``."""
    parts: list[list[int]] = []
    for v in sorted(values):
        if parts and parts[-1][1] == v - 1:
            parts[-1][1] = v
        else:
            parts.append([v, v])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in parts)


def attitude_from_matrix(r_world_from_body: F64) -> tuple[float, float, float]:
    """(roll, pitch, yaw) degrees, Z-Y-X, of a NED-from-FRD rotation matrix."""
    r = np.asarray(r_world_from_body, dtype=np.float64)
    pitch = -math.asin(max(-1.0, min(1.0, float(r[2, 0]))))
    roll = math.atan2(float(r[2, 1]), float(r[2, 2]))
    yaw = math.atan2(float(r[1, 0]), float(r[0, 0]))
    return math.degrees(roll), math.degrees(pitch), math.degrees(yaw)


def quaternion_matrix(w: float, x: float, y: float, z: float) -> F64:
    """Rotation matrix of the unit quaternion (w, x, y, z) (Hamilton, active)."""
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def body_attitude_for_camera(
    r_world_from_camera: F64, calibration: CameraCalibration
) -> tuple[float, float, float]:
    """The body attitude (deg) that, with the calibration's camera mount, points the camera as
    ``r_world_from_camera`` (NED from camera x right, y down, z along the optical axis) does:
    how a gimbal camera's own angles become the dataset's attitude."""
    mount = body_from_camera(calibration)
    return attitude_from_matrix(np.asarray(r_world_from_camera) @ mount.T)


def gimbal_camera_matrix(roll_deg: float, pitch_deg: float, yaw_deg: float) -> F64:
    """NED-from-camera rotation of a gimbal camera given as Z-Y-X angles of its forward axis
    (pitch -90 looks straight down, yaw is the camera's heading; image top toward the heading
    when it looks down), as DJI and others record them."""
    from c3_matcher.camera import rot_x, rot_y, rot_z

    forward_from_camera = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    yaw, pitch, roll = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    r = rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)
    return np.asarray(r @ forward_from_camera, dtype=np.float64)


def ground_elevation_sampler(dem: Path) -> Callable[[float, float], float | None]:
    """``(lat, lon) -> ground altitude (m)`` read from a DEM GeoTIFF (the tools' ``geo``
    extra: rasterio); None outside the raster or on nodata."""
    try:
        import rasterio
        from rasterio.warp import transform
    except ImportError:
        raise InvalidInputError(
            "--dem", "reading a DEM needs the geo extra: pip install 'c3-matcher-tools[geo]'"
        ) from None
    if not Path(dem).is_file():
        raise InvalidInputError("--dem", f"{dem}: no such file")
    try:
        ds = rasterio.open(dem)
    except Exception as exc:
        raise InvalidInputError("--dem", f"{dem}: not a readable raster: {exc}") from None
    if ds.crs is None:
        raise InvalidInputError("--dem", f"{dem}: no georeference (CRS)")
    band = ds.read(1, masked=True)
    nodata = np.ma.getmaskarray(band)

    def at(lat: float, lon: float) -> float | None:
        xs, ys = transform("EPSG:4326", ds.crs, [lon], [lat])
        row, col = ds.index(xs[0], ys[0])
        if not (0 <= row < ds.height and 0 <= col < ds.width) or bool(nodata[row, col]):
            return None
        return float(band[row, col])

    return at


def _names(shots: Sequence[Shot], shown: int = 3) -> str:
    """The first ``shown`` shots' names, then how many more."""
    more = f" and {len(shots) - shown} more" if len(shots) > shown else ""
    return ", ".join(s.name for s in shots[:shown]) + more


_ORDER_HINT = "--interval (s between images) and --time-offset (log time of the first image)"


def _no_time_source(track: LogTrack, shots: Sequence[Shot], untimed: Sequence[Shot]) -> str:
    """Why ``auto`` finds no way to put images without a camera trigger on the log's clock, and
    the options that would."""
    n, timed = len(shots), len(shots) - len(untimed)
    head = f"{track.source}: no camera trigger in the log"
    if not timed:
        return f"{head}, and none of the {n} images states a capture time: give {_ORDER_HINT}"
    if track.utc_offset_s is None:
        return (
            f"{head}, and it states no UTC time (no GNSS time) to meet the images' own times: "
            f"give {_ORDER_HINT}"
        )
    return (
        f"{head}, and {len(untimed)} of the {n} images state no capture time "
        f"({_names(untimed)}): give --time-source exif to import the {timed} that do by their "
        f"own time, or {_ORDER_HINT} to place all {n} in file order"
    )


def _trigger_count_refusal(
    track: LogTrack, shots: Sequence[Shot], triggers: F64, untimed: Sequence[Shot]
) -> str:
    """Why ``auto`` will not pair ``shots`` with a different number of ``triggers``: the counts,
    why order is wrong, why time cannot be used, and the ways out."""
    n = len(shots)
    if len(untimed) == n:
        why = f"none of the {n} images states a capture time"
    elif untimed:
        why = f"{len(untimed)} of the {n} images state no capture time ({_names(untimed)})"
    else:
        why = "the log states no UTC time (no GNSS time)"
    ways = ["remove the images without a trigger"]
    if track.utc_offset_s is not None and len(untimed) < n:
        those = f"the {n - len(untimed)} that state one, " if untimed else ""
        ways.append(f"give --time-source exif ({those}each by its own time)")
    ways.append("give --time-source trigger to pair them in order anyway")
    damaged = f" (the log is damaged or truncated: {track.damage})" if track.damage else ""
    return (
        f"{track.source}: {triggers.size} camera trigger(s) in the log{damaged} but {n} image(s): "
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


def _triggers_by_time(
    track: LogTrack, shots: Sequence[Shot], triggers: F64, options: ImportOptions
) -> tuple[list[tuple[Shot, float]], list[tuple[str, str]], str]:
    """Each image paired with the camera trigger nearest its own UTC time (plus
    ``--time-offset``), each trigger used once (by the image nearest it), at the trigger's time.

    Tolerance: ``--max-gap`` (default 1 s: whole-second EXIF times and camera clocks a fraction
    of a second off GNSS time) but at most half the median spacing of the triggers, so that an
    image is never nearer its neighbour's trigger than its own; an image farther than that from
    every trigger is left unpaired and reported, as are the triggers left without an image."""
    assert track.utc_offset_s is not None
    steps = np.diff(triggers)
    steps = steps[steps > 0]
    tol = min(options.max_gap_s, float(np.median(steps)) / 2 if steps.size else math.inf)
    own = [float(s.t_s or 0.0) - track.utc_offset_s + options.time_offset_s for s in shots]
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
            skipped.append(
                (
                    shot.name,
                    f"no camera trigger within {tol:g} s of its own time ({t:.2f} s on the "
                    f"log's clock; the nearest at {at:.2f} s)",
                )
            )
        elif owner[j] != k:
            skipped.append(
                (
                    shot.name,
                    f"its nearest camera trigger ({at:.2f} s) is nearer the time of "
                    f"{shots[owner[j]].name}",
                )
            )
        else:
            taken.append((shot, at))
    if not taken:
        raise InvalidInputError(
            "--time-source",
            f"{track.source}: {triggers.size} camera trigger(s) in the log but {len(shots)} "
            f"image(s), and no image's own time lies within {tol:g} s of a trigger (images at "
            f"{min(own):.1f} .. {max(own):.1f} s, triggers at {triggers[0]:.1f} .. "
            f"{triggers[-1]:.1f} s on the log's clock): the camera's clock is off "
            "(--time-offset), or give --time-source trigger to pair them in order",
        )
    how = (
        f"camera trigger nearest each image's own UTC time, within {tol:g} s "
        f"({triggers.size} in the log, {len(shots)} image(s): "
        f"{_unpaired(len(shots) - len(taken), triggers.size - len(taken))})"
    )
    return taken, skipped, how


def match_shots(
    track: LogTrack, shots: Sequence[Shot], options: ImportOptions
) -> tuple[list[tuple[Shot, float]], list[tuple[str, str]], str]:
    """Each shot's time on the log's clock: ([(shot, t_s)], [(name, why skipped)], how).

    ``auto``: a video's frames keep the video's clock (the log's camera triggers are a stills
    camera's). Photos take the camera triggers in order when the log has exactly as many;
    with another count, each photo the trigger nearest its own UTC time
    (:func:`_triggers_by_time`) when every photo states one and the log states UTC, else
    refused: in order, one missing or extra photo would shift every later one onto another's
    pose. Without triggers: the photos' own UTC times, else file order with ``--interval``.
    ``trigger`` pairs in order whatever the counts, and ``how`` says how many were left
    unpaired. Raises InvalidInputError when no image falls within the log's time span (images
    of another flight) or the chosen time source cannot be used."""
    src = options.time_source
    triggers = track.triggers_s if track.triggers_s is not None else np.zeros(0)
    video = bool(shots) and all("relative_s" in s.own for s in shots)
    untimed = [s for s in shots if s.t_s is None]
    if src == "auto":
        if video:
            src = "order"
        elif triggers.size == len(shots) and triggers.size:
            src = "trigger"
        elif triggers.size:
            if untimed or track.utc_offset_s is None:
                raise InvalidInputError(
                    "--time-source", _trigger_count_refusal(track, shots, triggers, untimed)
                )
            src = "trigger time"
        elif shots and not untimed and track.utc_offset_s is not None:
            src = "exif"
        elif options.interval_s is not None:
            src = "order"
        else:
            raise InvalidInputError("--time-source", _no_time_source(track, shots, untimed))
    taken: list[tuple[Shot, float]] = []
    skipped: list[tuple[str, str]] = []
    off = options.time_offset_s
    if src == "trigger":
        if not triggers.size:
            raise InvalidInputError("--time-source", f"{track.source}: no camera trigger")
        for i, shot in enumerate(shots):
            if i < triggers.size:
                taken.append((shot, float(triggers[i]) + off))
            else:
                skipped.append((shot.name, f"no camera trigger left ({triggers.size} in the log)"))
        how = f"camera trigger ({triggers.size} in the log, {len(shots)} image(s))"
        if triggers.size != len(shots):
            left = _unpaired(max(len(shots) - triggers.size, 0), max(triggers.size - len(shots), 0))
            how = (
                f"camera trigger in file order, as asked ({triggers.size} in the log, "
                f"{len(shots)} image(s): {left})"
            )
    elif src == "trigger time":
        taken, skipped, how = _triggers_by_time(track, shots, triggers, options)
    elif src == "exif":
        if track.utc_offset_s is None:
            raise InvalidInputError(
                "--time-source", f"{track.source}: the log states no UTC time (no GNSS time)"
            )
        for shot in shots:
            if shot.t_s is None:
                skipped.append((shot.name, "the image states no capture time"))
            else:
                taken.append((shot, shot.t_s - track.utc_offset_s + off))
        how = "the images' own UTC time stamps against the log's UTC time"
    else:
        if options.interval_s is None and not video:
            raise InvalidInputError("--interval", "file order needs --interval (s between images)")
        step = options.interval_s or 0.0
        taken = [(s, off + float(s.own.get("relative_s", i * step))) for i, s in enumerate(shots)]
        how = "video clock" if video else f"file order, one image every {step:g} s"
        if video and triggers.size and options.time_source == "auto":
            how += (
                f" (the log's {triggers.size} camera trigger(s), a stills camera's, not used: "
                "--time-source trigger to pair them in order)"
            )
    lo, hi = track.span
    tol = options.max_gap_s
    inside = [(s, t) for s, t in taken if lo - tol <= t <= hi + tol]
    if taken and not inside:
        first, last = min(t for _, t in taken), max(t for _, t in taken)
        raise InvalidInputError(
            track.source,
            f"no image falls within the log's time span ({lo:.1f} .. {hi:.1f} s; the images at "
            f"{first:.1f} .. {last:.1f} s): images and log of different flights, or a time "
            "offset to give (--time-offset)",
        )
    skipped += [
        (s.name, f"at {t:.1f} s, outside the log ({lo:.1f} .. {hi:.1f} s)")
        for s, t in taken
        if not lo - tol <= t <= hi + tol
    ]
    return inside, skipped, how


@dataclass(frozen=True)
class _Frame:
    shot: Shot
    t_s: float
    lat: float
    lon: float
    alt_m: float
    attitude: tuple[float, float, float]
    height_m: float
    height_source: str
    flags: tuple[str, ...]
    gnss: dict[str, Any]


def assemble_frames(
    track: LogTrack,
    matched: Sequence[tuple[Shot, float]],
    options: ImportOptions,
    attitude_of: Callable[[Shot, float], tuple[float, float, float] | None] | None = None,
) -> tuple[list[_Frame], list[tuple[str, str]]]:
    """Per matched shot, the telemetry at its time (see the module docstring); frames without
    a position are returned as skipped. ``attitude_of`` overrides the log's attitude per shot
    (the image's own gimbal angles)."""
    gap = options.max_gap_s
    dem = ground_elevation_sampler(options.dem) if options.dem is not None else None
    frames: list[_Frame] = []
    skipped: list[tuple[str, str]] = []
    for shot, t in matched:
        flags: list[str] = []
        pos = _finite_position(track.position.at(t, gap) if track.position is not None else None)
        fix = track.gnss.at(t, gap) if track.gnss is not None else None
        if track.per_image and "lat" in shot.own:
            own = shot.own
            fix = np.array(
                [own["lat"], own["lon"], own.get("alt_m", math.nan), math.nan, 3.0],
                dtype=np.float64,
            )
        if pos is None and fix is not None:
            pos = _finite_position(fix[:3])
        if pos is None:
            skipped.append((shot.name, f"no position within {gap:g} s of {t:.2f} s"))
            continue
        lat, lon, alt = (float(v) for v in pos[:3])
        accuracy = float(fix[3]) if fix is not None and math.isfinite(fix[3]) else None
        fix_type = int(fix[4]) if fix is not None and math.isfinite(fix[4]) else None
        degraded = (
            fix is None
            or _finite_position(fix[:3]) is None
            or (fix_type is not None and fix_type < 3)
            or (accuracy is not None and accuracy > options.gnss_degraded_m)
        )
        if degraded:
            flags.append("gnss_degraded")
        attitude = attitude_of(shot, t) if attitude_of is not None else None
        if attitude is None and track.attitude is not None:
            a = track.attitude.at(t, gap)
            attitude = None if a is None else (float(a[0]), float(a[1]), float(a[2]))
        if attitude is None or max(abs(attitude[0]), abs(attitude[1])) >= 89.0:
            flags.append("attitude_assumed")
            attitude = (0.0, 0.0, _course_deg(track, t))
        height, source = _height(track, shot, t, lat, lon, alt, options, dem)
        frames.append(
            _Frame(
                shot,
                t,
                lat,
                lon,
                alt,
                attitude,
                height,
                source,
                tuple(flags),
                {
                    "gnss_accuracy_m": accuracy,
                    "gnss_fix": fix_type,
                    "gnss_degraded": degraded,
                },
            )
        )
    _fill_heights(frames)
    return frames, skipped


def _finite_position(pos: F64 | None) -> F64 | None:
    return pos if pos is not None and bool(np.all(np.isfinite(pos[:2]))) else None


def _course_deg(track: LogTrack, t: float) -> float:
    """The track's course over ground at ``t`` (deg from north), 0 when it cannot be told."""
    series = track.position if track.position is not None else track.gnss
    if series is None or len(series) < 2:
        return 0.0
    a, b = series.at(t - 1.0, 5.0), series.at(t + 1.0, 5.0)
    if a is None or b is None or not np.all(np.isfinite([*a[:2], *b[:2]])):
        return 0.0
    dn = (b[0] - a[0]) * 111_320.0
    de = (b[1] - a[1]) * 111_320.0 * math.cos(math.radians(a[0]))
    return 0.0 if math.hypot(dn, de) < 1.0 else math.degrees(math.atan2(de, dn))


def _height(
    track: LogTrack,
    shot: Shot,
    t: float,
    lat: float,
    lon: float,
    alt: float,
    options: ImportOptions,
    dem: Callable[[float, float], float | None] | None,
) -> tuple[float, str]:
    """(height above ground m, source); NaN and the reason when no source gives one."""
    if "height_m" in shot.own and math.isfinite(shot.own["height_m"]):
        return float(shot.own["height_m"]), str(shot.own.get("height_source", "image metadata"))
    h = track.height.at(t, options.max_gap_s) if track.height is not None else None
    if h is not None and h[0] > 0:
        return float(h[0]), f"{track.height.name} (above ground)"  # type: ignore[union-attr]
    if not math.isfinite(alt):
        return math.nan, "no altitude"
    if dem is not None:
        ground = dem(lat, lon)
        if ground is not None:
            return alt - ground, "altitude - DEM"
        return math.nan, "the DEM has no value here"
    if options.ground_elevation_m is not None:
        return alt - options.ground_elevation_m, "altitude - ground elevation"
    if track.home_alt_m is not None:
        return alt - track.home_alt_m, "altitude - home altitude"
    return math.nan, "no ground elevation, DEM or home altitude"


def _fill_heights(frames: list[_Frame]) -> None:
    good = [i for i, f in enumerate(frames) if math.isfinite(f.height_m) and f.height_m > 0]
    if not good:
        return
    for i, f in enumerate(frames):
        if i in good:
            continue
        j = min(good, key=lambda g: (abs(g - i), g))
        why = f.height_source
        if math.isfinite(f.height_m):
            why += f" gave {f.height_m:.1f} m"
        frames[i] = _Frame(
            f.shot,
            f.t_s,
            f.lat,
            f.lon,
            f.alt_m,
            f.attitude,
            frames[j].height_m,
            f"nearest frame's height ({why})",
            (*f.flags, "height_assumed"),
            f.gnss,
        )


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
    from c3_matcher_tools.dataset.importer import (
        ImportSpec,
        TelemetryRow,
        imported_frame,
        propose_from_store,
    )

    out = Path(out)
    check_output_dir(out, force=force, inputs=(track.source, options.store, options.dem))
    if not Path(options.store).is_file():
        raise InvalidInputError("STORE", f"{options.store}: no such tile store")
    if not shots:
        raise InvalidInputError("IMAGES", "no image found")
    if track.position is None and track.gnss is None:
        raise InvalidInputError(track.source, "the log holds no position (GNSS or estimator)")
    matched, unmatched, how = match_shots(track, shots, options)
    frames, no_pos = assemble_frames(track, matched, options, attitude_of)
    rank = {s.name: i for i, s in enumerate(shots)}
    skipped = [*skipped, *sorted([*unmatched, *no_pos], key=lambda x: rank.get(x[0], -1))]
    if not frames:
        raise InvalidInputError(track.source, "no image could be placed: " + _why(skipped))
    _check_same_flight(track, frames)
    if not any(math.isfinite(f.height_m) and f.height_m > 0 for f in frames):
        raise InvalidInputError(
            "--ground-elevation",
            f"{track.source}: no height above ground for any frame (heights "
            f"{', '.join(sorted({f.height_source for f in frames}))}): give --ground-elevation "
            "(the ground's altitude, m, in the log's datum) or --dem",
        )
    calibration = options.calibration
    size = options.calibration.image_size
    images: list[bytes] = []
    for f in frames:
        data = f.shot.read()
        problem = image_problem(data, size)
        if problem:
            raise InvalidInputError("IMAGES", f"{f.shot.name}: {problem}")
        images.append(data)
    proposer = ImportSpec(
        Path(),
        Path(track.source),
        Path(),
        Path(options.store),
        uncertainty_m=options.uncertainty_m,
        candidates=options.candidates,
        zoom=options.zoom,
        candidate_size_px=options.candidate_size_px,
        seed=options.seed,
    )
    rows = [
        TelemetryRow(i, f.t_s, f.shot.name, f.lat, f.lon, f.height_m, *f.attitude)
        for i, f in enumerate(frames)
    ]
    proposed = propose_from_store(rows, calibration, proposer)
    zoom, proposals = proposed.zoom, proposed.looks
    attribution, tiles_source = proposed.attribution, proposed.tiles_source
    proposed.refuse_outside(
        track.source, lambda r: r.image, hint=" (log and store of different places?)", shown=5
    )
    label = name or out.name
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
    report = ImportReport(
        dataset=str(out),
        source=Path(track.source).name,
        kind=track.kind,
        frames=len(records),
        skipped=tuple(skipped),
        time_source=how,
        time_offset_s=options.time_offset_s,
        height_sources=_count(f.height_source for f in frames),
        attitude_assumed=tuple(i for i, f in enumerate(frames) if "attitude_assumed" in f.flags),
        height_assumed=tuple(i for i, f in enumerate(frames) if "height_assumed" in f.flags),
        gnss_degraded=tuple(i for i, f in enumerate(frames) if "gnss_degraded" in f.flags),
        zoom=zoom,
        notes=track.notes,
    )
    meta = {
        "name": label,
        "store": "tiles.mbtiles",
        "candidate_size_px": options.candidate_size_px,
        "zoom": zoom,
        "tiles_source": tiles_source,
        "frames_source": f"imported: {Path(track.source).name} ({track.kind})",
        "spec": {
            "kind": "import",
            "log": Path(track.source).name,
            "log_kind": track.kind,
            "time_source": how,
            "time_offset_s": options.time_offset_s,
            "store": Path(options.store).name,
            "uncertainty_m": options.uncertainty_m,
            "candidates": options.candidates,
            "candidate_size_px": options.candidate_size_px,
            "zoom": zoom,
            "seed": options.seed,
            **(spec or {}),
        },
        "import": {k: v for k, v in report.to_json().items() if k != "dataset"},
        "attribution": attribution,
    }
    with atomic_directory(out, force=force) as tmp:
        (tmp / "frames").mkdir()
        for rec, data in zip(records, images, strict=True):
            (tmp / rec.image).write_bytes(data)
        shutil.copyfile(options.store, tmp / "tiles.mbtiles")
        write_dataset(tmp, meta, calibration, records)
    return report


MAX_OWN_GPS_OFFSET_M = 500.0
"""Images whose own GPS lies farther than this (median) from the log's position at their
times belong to another flight (or need a time offset)."""


def _check_same_flight(track: LogTrack, frames: Sequence[_Frame]) -> None:
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


def image_problem(data: bytes, size: tuple[int, int]) -> str | None:
    """Why the encoded image ``data`` cannot be a frame of a ``size`` (w, h) camera, or None:
    every import checks its images with this (a truncated JPEG is not readable)."""
    import cv2

    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        return "not a readable image"
    h, w = image.shape[:2]
    if (w, h) != tuple(size):
        return f"is {w}x{h} px, the calibration says {size[0]}x{size[1]}"
    return None
