"""Per-frame telemetry from a log's track at each image's time: position, attitude, height
above ground and GNSS quality.

A frame's height above ground is the image's own, else the log's rangefinder (a range along
the tilted body made vertical with the attitude, as ArduPilot does), else its altitude above
sea level (a bag's NavSatFix altitude above the ellipsoid less ``--geoid-height``) minus the
DEM, the ground elevation or the home altitude in force; its height source says which.

A frame whose time finds no attitude sample is imported level with the yaw of the GNSS course
(flag ``attitude_assumed``); one without a height above ground gets the nearest frame's height
(flag ``height_assumed``); one whose GNSS is absent, without a 3D fix, or less accurate than the
degraded bound is flagged ``gnss_degraded`` (its position comes from the estimator when the log
has one). Frames without any position are skipped with their reason: no candidate can be
proposed for them.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from c3_matcher.arrays import F64
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.sources.options import ImportOptions, check_geoid_height
from c3_matcher_tools.dataset.sources.track import LogTrack, Shot
from c3_matcher_tools.geodesy import flat_offset_m

__all__ = ["Frame", "assemble_frames", "ground_elevation_sampler"]


def ground_elevation_sampler(dem: Path) -> Callable[[float, float], float | None]:
    """``(lat, lon) -> ground altitude (m)`` read from a DEM GeoTIFF (the tools' ``geo``
    extra: rasterio); None outside the raster or on nodata. A value is the pixel's as the file
    states it: its stored number times the band's scale plus its offset (an int16 DEM of
    decimetres states a scale of 0.1), in metres (a band whose unit is feet is converted; one
    of another stated unit is refused). The DEM's first band is read whole and the file closed
    before this returns; one that cannot be opened, is not georeferenced or whose pixels cannot
    be read is refused (InvalidInputError naming ``--dem`` and the file, with GDAL's own words
    and no Python warning)."""
    return _read_dem(dem).at


@dataclass(frozen=True)
class _DemGrid:
    """A DEM's first band as stored (``band``; ``nodata`` True where it has no value), where it
    lies (``crs``, ``affine``) and what makes its numbers metres: value = (stored * ``scale`` +
    ``offset``) * ``metres`` (the metres of its stated unit)."""

    band: Any
    nodata: Any
    crs: Any
    affine: Any
    scale: float
    offset: float
    metres: float

    def at(self, lat: float, lon: float) -> float | None:
        """The ground's altitude (m) at (lat, lon); None outside the raster or on nodata."""
        from rasterio.transform import rowcol
        from rasterio.warp import transform

        xs, ys = transform("EPSG:4326", self.crs, [lon], [lat])
        row, col = (int(v) for v in rowcol(self.affine, xs[0], ys[0]))
        height, width = self.band.shape
        if not (0 <= row < height and 0 <= col < width) or bool(self.nodata[row, col]):
            return None
        return (float(self.band[row, col]) * self.scale + self.offset) * self.metres


def _read_dem(dem: Path) -> _DemGrid:
    """The DEM GeoTIFF ``dem`` read (see :func:`ground_elevation_sampler`)."""
    try:
        import rasterio
        from rasterio.errors import NotGeoreferencedWarning
    except ImportError:
        raise InvalidInputError(
            "--dem", "reading a DEM needs the geo extra: pip install 'c3-matcher-tools[geo]'"
        ) from None
    if not Path(dem).is_file():
        why = "is a directory, not a GeoTIFF" if Path(dem).is_dir() else "no such file"
        raise InvalidInputError("--dem", f"{dem}: {why}")
    with warnings.catch_warnings():  # a raster without a transform: refused below, by name
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        try:
            ds = rasterio.open(dem)
        except Exception as exc:
            why = f"not a readable raster ({_gdal_why(exc)})"
            raise InvalidInputError("--dem", f"{dem}: {why}") from None
    with ds:
        if ds.crs is None:
            raise InvalidInputError("--dem", f"{dem}: no georeference (CRS)")
        if ds.count < 1:
            raise InvalidInputError("--dem", f"{dem}: no raster band")
        metres = _unit_metres(dem, ds.units[0])
        try:
            band = ds.read(1, masked=True)
        except Exception as exc:  # rasterio's "Read failed": a truncated or damaged file
            why = f"damaged raster, its pixels cannot be read ({_gdal_why(exc)})"
            raise InvalidInputError("--dem", f"{dem}: {why}") from None
        scale, offset = float(ds.scales[0]), float(ds.offsets[0])
        nodata = np.ma.getmaskarray(band)
        return _DemGrid(band, nodata, ds.crs, ds.transform, scale, offset, metres)


METRE_UNITS = ("", "m", "metre", "metres", "meter", "meters")
"""A DEM band's unit (lower case) that says metres, or says nothing (taken as metres)."""
FOOT_UNITS = {
    "ft": 0.3048,
    "foot": 0.3048,
    "feet": 0.3048,
    "international foot": 0.3048,
    "us survey foot": 1200 / 3937,
    "us survey feet": 1200 / 3937,
    "ftus": 1200 / 3937,
    "us-ft": 1200 / 3937,
}
"""A DEM band's unit (lower case) in feet, and the metres of one: its heights are converted."""


def _unit_metres(dem: Path, unit: str | None) -> float:
    """The metres of one of the DEM band's stated ``unit`` (:data:`METRE_UNITS`,
    :data:`FOOT_UNITS`); refused naming ``--dem`` and the unit when it is neither."""
    said = (unit or "").strip().lower()
    if said in METRE_UNITS:
        return 1.0
    if said in FOOT_UNITS:
        return FOOT_UNITS[said]
    raise InvalidInputError(
        "--dem",
        f"{dem}: its band states heights in {unit!r}, neither metres nor feet: give a DEM in "
        "metres (gdal_edit.py -units m, where its numbers are metres)",
    )


def _gdal_why(exc: BaseException) -> str:
    """GDAL's own words for a failed open or read: the innermost cause of rasterio's exception
    (whose message only says "see previous exception"), on one line."""
    while exc.__cause__ is not None or exc.__context__ is not None:
        exc = exc.__cause__ or exc.__context__  # type: ignore[assignment]
    return " ".join(str(exc).split())


@dataclass(frozen=True)
class Frame:
    """One image placed on the log: its time ``t_s``, position (``alt_m`` above sea level, a
    bag's so once ``--geoid-height`` is given; NaN when the log has none), attitude (deg),
    height above ground and where it came from, its flags and GNSS fix."""

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
) -> tuple[list[Frame], list[tuple[str, str]]]:
    """Per matched shot, the telemetry at its time (see the module docstring); frames without
    a position are returned as skipped. ``attitude_of`` overrides the log's attitude per shot
    (the image's own gimbal angles)."""
    ground_given = options.dem is not None or options.ground_elevation_m is not None
    check_geoid_height(
        track.source,
        ellipsoidal=track.ellipsoidal,
        ground_given=ground_given,
        geoid_height_m=options.geoid_height_m,
    )
    dem = ground_elevation_sampler(options.dem) if options.dem is not None else None
    sources = _Sources(track, options, attitude_of, dem)
    frames: list[Frame] = []
    skipped: list[tuple[str, str]] = []
    for shot, t in matched:
        frame = _frame(sources, shot, t)
        if frame is None:
            skipped.append((shot.name, f"no position within {options.max_gap_s:g} s of {t:.2f} s"))
        else:
            frames.append(frame)
    _fill_heights(frames)
    return frames, skipped


@dataclass(frozen=True)
class _Sources:
    """What a frame's telemetry is read from: the log's track, the import's options, the
    images' own attitude (when given) and the DEM's ground altitude (when given)."""

    track: LogTrack
    options: ImportOptions
    attitude_of: Callable[[Shot, float], tuple[float, float, float] | None] | None
    dem: Callable[[float, float], float | None] | None


@dataclass(frozen=True)
class _GnssQuality:
    """A frame's GNSS fix as the dataset states it: the stated horizontal accuracy (m) and
    fix type (None when not stated), and whether it is absent or degraded."""

    accuracy_m: float | None
    fix_type: int | None
    degraded: bool

    @classmethod
    def of(cls, fix: F64 | None, degraded_m: float) -> _GnssQuality:
        """Degraded: no fix, no position in it, less than a 3D fix or an accuracy worse than
        ``degraded_m``."""
        accuracy = float(fix[3]) if fix is not None and math.isfinite(fix[3]) else None
        fix_type = int(fix[4]) if fix is not None and math.isfinite(fix[4]) else None
        degraded = (
            fix is None
            or _finite_position(fix[:3]) is None
            or (fix_type is not None and fix_type < 3)
            or (accuracy is not None and accuracy > degraded_m)
        )
        return cls(accuracy, fix_type, degraded)

    def telemetry(self) -> dict[str, Any]:
        return {
            "gnss_accuracy_m": self.accuracy_m,
            "gnss_fix": self.fix_type,
            "gnss_degraded": self.degraded,
        }


def _frame(sources: _Sources, shot: Shot, t: float) -> Frame | None:
    """``shot`` at log time ``t`` with its telemetry, flagged where it is degraded or assumed;
    None when no position lies within the gap."""
    track, options = sources.track, sources.options
    fix = _gnss_fix(track, shot, t, options.max_gap_s)
    pos = _position(track, t, options.max_gap_s, fix)
    if pos is None:
        return None
    lat, lon = float(pos[0]), float(pos[1])
    alt = _sea_level(track, options, float(pos[2]))
    gnss = _GnssQuality.of(fix, options.gnss_degraded_m)
    attitude, assumed = _attitude(sources, shot, t)
    height, source = _height(sources, shot, t, (lat, lon, alt))
    flags = tuple(
        flag for flag, on in (("gnss_degraded", gnss.degraded), ("attitude_assumed", assumed)) if on
    )
    return Frame(shot, t, lat, lon, alt, attitude, height, source, flags, gnss.telemetry())


def _gnss_fix(track: LogTrack, shot: Shot, t: float, gap: float) -> F64 | None:
    """The GNSS fix (lat, lon, alt, accuracy, fix type) at ``t``: the image's own position
    when each image states one, else the log's receiver within ``gap``."""
    fix = track.gnss.at(t, gap) if track.gnss is not None else None
    if track.per_image and "lat" in shot.own:
        own = shot.own
        fix = np.array(
            [own["lat"], own["lon"], own.get("alt_m", math.nan), math.nan, 3.0],
            dtype=np.float64,
        )
    return fix


def _position(track: LogTrack, t: float, gap: float, fix: F64 | None) -> F64 | None:
    """The vehicle's position at ``t``: the log's estimate, else the GNSS fix; None when
    neither has a finite one within ``gap``. An estimate without an altitude (one its
    estimator marked invalid) takes the fix's."""
    pos = _finite_position(track.position.at(t, gap) if track.position is not None else None)
    if pos is not None and not math.isfinite(pos[2]) and fix is not None:
        pos = np.array([pos[0], pos[1], fix[2]], dtype=np.float64)
    if pos is None and fix is not None:
        pos = _finite_position(fix[:3])
    return pos


def _attitude(sources: _Sources, shot: Shot, t: float) -> tuple[tuple[float, float, float], bool]:
    """(attitude, whether assumed): the image's own, else the log's at ``t``; level with the
    yaw of the course when neither gives one or it is near vertical."""
    attitude = sources.attitude_of(shot, t) if sources.attitude_of is not None else None
    if attitude is None and sources.track.attitude is not None:
        a = sources.track.attitude.at(t, sources.options.max_gap_s)
        attitude = None if a is None else (float(a[0]), float(a[1]), float(a[2]))
    if attitude is None or max(abs(attitude[0]), abs(attitude[1])) >= 89.0:
        return (0.0, 0.0, _course_deg(sources.track, t)), True
    return attitude, False


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
    dn, de = flat_offset_m(float(a[0]), float(a[1]), float(b[0]), float(b[1]))
    return 0.0 if math.hypot(dn, de) < 1.0 else math.degrees(math.atan2(de, dn))


def _height(
    sources: _Sources, shot: Shot, t: float, place: tuple[float, float, float]
) -> tuple[float, str]:
    """(height above ground m, source) of the frame at ``place`` (lat, lon, altitude above sea
    level: :func:`_sea_level`): the image's own, else the log's rangefinder (made vertical:
    :func:`_rangefinder`), else the altitude minus the DEM, the ground elevation or the home
    altitude in force; NaN and the reason when no source gives one."""
    track, options = sources.track, sources.options
    if "height_m" in shot.own and math.isfinite(shot.own["height_m"]):
        return float(shot.own["height_m"]), str(shot.own.get("height_source", "image metadata"))
    h = track.height.at(t, options.max_gap_s) if track.height is not None else None
    if h is not None and h[0] > 0:
        return _rangefinder(track, t, float(h[0]), options.max_gap_s)
    lat, lon, alt = place
    if not math.isfinite(alt):
        return math.nan, "no altitude"
    datum = _datum(track, options)
    if sources.dem is not None:
        ground = sources.dem(lat, lon)
        if ground is not None:
            return alt - ground, f"{datum} - DEM"
        return math.nan, "the DEM has no value here"
    if options.ground_elevation_m is not None:
        ground_m = options.ground_elevation_m
        return alt - ground_m, f"{datum} - ground elevation {ground_m:g} m"
    home = track.home.held(t) if track.home is not None else None
    if home is not None:  # the home in force at the frame's time, re-set at arming or not
        home_m = _sea_level(track, options, float(home[0]))
        return alt - home_m, f"altitude - home altitude {home_m:.1f} m"
    return math.nan, "no ground elevation, DEM or home altitude"


def _sea_level(track: LogTrack, options: ImportOptions, alt: float) -> float:
    """The track's altitude ``alt`` above sea level: less the geoid height given where the
    track's altitudes are above the ellipsoid (a bag's NavSatFix); as it is otherwise (and
    where no geoid height is given: then no ground is, :func:`check_geoid_height`)."""
    if track.ellipsoidal and options.geoid_height_m is not None:
        return alt - options.geoid_height_m
    return alt


def _datum(track: LogTrack, options: ImportOptions) -> str:
    """What the altitude a ground is taken from is, as a height source names it: above sea
    level as the log states it, or above the ellipsoid less the geoid height given."""
    if not track.ellipsoidal:
        return "altitude above sea level"
    if options.geoid_height_m is None:
        return "altitude above the ellipsoid"
    return f"altitude above the ellipsoid - geoid height {options.geoid_height_m:g} m"


MIN_TILT_FACTOR = 0.707
"""The least cos(roll) cos(pitch) a rangefinder reading is multiplied by, as ArduPilot takes
its own (beyond 45 deg of tilt the beam meets the ground far from below the vehicle)."""


def _rangefinder(track: LogTrack, t: float, reading: float, gap: float) -> tuple[float, str]:
    """(height above ground m, source) of a rangefinder ``reading`` at ``t``: a range along the
    tilted body (:attr:`LogTrack.height_along_body`) times cos(roll) cos(pitch) at ``t`` (at
    least :data:`MIN_TILT_FACTOR`), as ArduPilot makes its own vertical; taken as it is where
    it is vertical already or no attitude lies within ``gap`` (said so)."""
    name = track.height.name if track.height is not None else "rangefinder"
    if not track.height_along_body:
        return reading, f"{name} (above ground)"
    a = track.attitude.at(t, gap) if track.attitude is not None else None
    if a is None or not bool(np.all(np.isfinite(a[:2]))):
        return reading, f"{name} (range along the body, taken as vertical: no attitude)"
    factor = math.cos(math.radians(float(a[0]))) * math.cos(math.radians(float(a[1])))
    return reading * max(factor, MIN_TILT_FACTOR), f"{name} x cos(roll) cos(pitch) (above ground)"


def _fill_heights(frames: list[Frame]) -> None:
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
        frames[i] = Frame(
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
