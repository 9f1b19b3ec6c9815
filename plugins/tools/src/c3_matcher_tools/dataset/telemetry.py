"""The telemetry CSV of a recorded flight, read and checked (:func:`read_telemetry_table`).

One row per frame, a header naming the columns (case-insensitive, any order, other columns
ignored):

    ==================  ==========================================================  ===========
    column (aliases)    meaning                                                     unit
    ==================  ==========================================================  ===========
    time_s (time)       capture time                                                seconds
    image (file,        image file name, relative to IMAGES_DIR                     -
      filename,
      image_file)
    lat (latitude)      vehicle position, WGS84                                     degrees
    lon (longitude)     vehicle position, WGS84                                     degrees
    altitude_m          height ABOVE GROUND (AGL)                                   metres
      (altitude,
      height_m, agl_m,
      height_agl_m)
    altitude_msl_m      or: altitude above mean sea level (the DEM's / ground         metres
      (alt_msl_m,       elevation's datum); height above ground = this minus the
      altitude_amsl_m,  ground elevation (``ground_elevation_m``) or the DEM at
      amsl_m, msl_m)    (lat, lon) (``dem``), which must then be given
    roll_deg (roll)     attitude, aerospace Z-Y-X (yaw, pitch, roll), NED body      degrees
    pitch_deg (pitch)   idem                                                        degrees
    yaw_deg (yaw)       idem; yaw from TRUE north, clockwise positive               degrees
    ==================  ==========================================================  ===========

Every row is checked before any is used: a refused value names its CSV line (the line its
record starts on: a quoted field may hold a line break), and so do two rows at one time
(:func:`refuse_lines`). An image name holding a line break or another control character is
refused: no file name meant holds one. Given IMAGES_DIR, each name is placed in it, and one
outside it or naming the file a row before names is refused
(:mod:`c3_matcher_tools.dataset.image_names`).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import re
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from c3_matcher.dto import MAX_HEIGHT_ABOVE_GROUND_M, Attitude
from c3_matcher.errors import InvalidInputError
from c3_matcher.file_kinds import special_kind
from c3_matcher_tools.dataset.image_names import place_images
from c3_matcher_tools.dataset.sources.frames import ground_elevation_sampler
from c3_matcher_tools.dataset.sources.options import number_ranges
from c3_matcher_tools.dataset.sources.pairing import same_times

__all__ = [
    "COLUMNS",
    "HEIGHT_COLUMNS",
    "Telemetry",
    "TelemetryRow",
    "read_telemetry_table",
    "refuse_lines",
]

#: canonical column -> accepted header names (case-insensitive)
COLUMNS: dict[str, tuple[str, ...]] = {
    "time_s": ("time_s", "time"),
    "image": ("image", "file", "filename", "image_file"),
    "lat": ("lat", "latitude"),
    "lon": ("lon", "longitude"),
    "roll_deg": ("roll_deg", "roll"),
    "pitch_deg": ("pitch_deg", "pitch"),
    "yaw_deg": ("yaw_deg", "yaw"),
}
#: the height columns, one of which must be present: above ground, or above mean sea level
HEIGHT_COLUMNS: dict[str, tuple[str, ...]] = {
    "altitude_m": ("altitude_m", "altitude", "height_m", "agl_m", "height_agl_m"),
    "altitude_msl_m": ("altitude_msl_m", "alt_msl_m", "altitude_amsl_m", "amsl_m", "msl_m"),
}
MAX_PROBLEMS = 10
MAX_ABS_TIME_S = 4e9  # |time_s| beyond this (126 years) is not a capture time (ns fit int64)
AGREE_M = 30.0  # both height columns given: altitude - height must be the ground to this
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")  # a line break, a tab, a NUL: in no file name meant


@dataclass(frozen=True)
class TelemetryRow:
    """One telemetry record (see the module docstring); ``line`` is its CSV line number."""

    line: int
    time_s: float
    image: str
    lat: float
    lon: float
    altitude_m: float
    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    altitude_msl_m: float | None = None  # the row's altitude above sea level, when given

    @property
    def attitude(self) -> Attitude:
        return Attitude.from_degrees(self.roll_deg, self.pitch_deg, self.yaw_deg)


def _find(lowered: dict[str, str], aliases: tuple[str, ...]) -> str | None:
    return next((lowered[a] for a in aliases if a in lowered), None)


def _repeated_columns(header: list[str]) -> list[str]:
    """The columns ``header`` gives more than once: a name repeated, or two aliases of one."""
    names = [h.strip().lower() for h in header]
    repeated = [f"{n!r} twice" for n in dict.fromkeys(names) if n and names.count(n) > 1]
    for aliases in (*COLUMNS.values(), *HEIGHT_COLUMNS.values()):
        given = [a for a in aliases if a in names]
        if len(given) > 1:
            repeated.append(" and ".join(repr(a) for a in given))
    return repeated


def _column_map(header: list[str], path: Path) -> dict[str, str]:
    """Canonical column -> header name; at least one of :data:`HEIGHT_COLUMNS`. A column given
    more than once is refused: which one holds the values would be a guess."""
    repeated = _repeated_columns(header)
    if repeated:
        raise InvalidInputError(
            str(path),
            f"telemetry CSV gives a column more than once ({'; '.join(repeated)}); "
            f"header: {header}",
        )
    lowered = {h.strip().lower(): h for h in header}
    found: dict[str, str] = {}
    missing = []
    for name, aliases in COLUMNS.items():
        hit = _find(lowered, aliases)
        if hit is None:
            missing.append(f"{name} (or {', '.join(aliases[1:])})" if aliases[1:] else name)
        else:
            found[name] = hit
    for name, aliases in HEIGHT_COLUMNS.items():
        hit = _find(lowered, aliases)
        if hit is not None:
            found[name] = hit
    if not any(k in found for k in HEIGHT_COLUMNS):
        missing.append(
            "a height: altitude_m (height above ground; or altitude, height_m, agl_m) or "
            "altitude_msl_m (above sea level, with --ground-elevation or --dem)"
        )
    if missing:
        raise InvalidInputError(
            str(path), f"telemetry CSV lacks column(s) {'; '.join(missing)}; header: {header}"
        )
    return found


@dataclass(frozen=True)
class Telemetry:
    """The checked rows (sorted by time) and how their heights above ground were obtained:
    ``height_source`` in words, ``columns`` canonical -> the CSV's header names; ``notes``:
    what the import should say of the values (:func:`radians_note`)."""

    rows: tuple[TelemetryRow, ...]
    height_source: str
    columns: dict[str, str]
    notes: tuple[str, ...] = ()


def refuse_lines(path: Path, problems: list[tuple[int, str]]) -> None:
    """Refuse ``path`` when there are ``problems`` ((line, why) each) with one line naming the
    first problems in full and every further line by number."""
    if not problems:
        return
    shown = "; ".join(text for _, text in problems[:MAX_PROBLEMS])
    rest = [n for n, _ in problems[MAX_PROBLEMS:]]
    more = f" (and {len(rest)} more, on lines {number_ranges(rest)})" if rest else ""
    raise InvalidInputError(str(path), shown + more)


def _row_problem(values: dict[str, float], col: dict[str, str]) -> str | None:
    """Why a row's (finite) values are refused, naming the CSV's column, or None."""
    t = values["time_s"]
    if abs(t) > MAX_ABS_TIME_S:
        return (
            f"{col['time_s']} {t:g} is not a capture time in seconds (|time_s| <= "
            f"{MAX_ABS_TIME_S:g}; milliseconds or nanoseconds?)"
        )
    if not -90.0 <= values["lat"] <= 90.0:
        return f"{col['lat']} {values['lat']:g} outside [-90, 90] deg"
    if not -180.0 <= values["lon"] <= 180.0:
        return f"{col['lon']} {values['lon']:g} outside [-180, 180] deg"
    for key in ("roll_deg", "pitch_deg"):
        if abs(values[key]) >= 90.0:
            return f"{col[key]} {values[key]:g}: |roll| and |pitch| must be < 90 deg"
    if abs(values["yaw_deg"]) > 360.0:
        return f"{col['yaw_deg']} {values['yaw_deg']:g} outside [-360, 360] deg"
    return None


def _height(
    values: dict[str, float],
    col: dict[str, str],
    ground: Any,
    spec_ground: float | None,
) -> tuple[float | None, str | None]:
    """(height above ground m, None) or (None, why refused) for one row. An altitude above
    sea level beside the height above ground is checked against the ground when one is given
    (else the height is taken as it is: there is nothing to check it against)."""
    agl = values.get("altitude_m")
    msl = values.get("altitude_msl_m")
    if msl is not None and (agl is None or ground is not None or spec_ground is not None):
        g = spec_ground if ground is None else ground(values["lat"], values["lon"])
        if g is None:
            where = f"({values['lat']:.6f}, {values['lon']:.6f})"
            return None, f"the DEM has no ground elevation at {where}"
        if agl is None:
            agl = msl - g
            if agl <= 0:
                return None, (
                    f"{col['altitude_msl_m']} {msl:g} m is not above the ground ({g:g} m): "
                    "altitude above sea level?"
                )
        elif abs(msl - agl - g) > AGREE_M:
            return None, (
                f"{col['altitude_msl_m']} {msl:g} m minus {col['altitude_m']} {agl:g} m is "
                f"{msl - agl:g} m, but the ground is at {g:g} m"
            )
    assert agl is not None
    name = col.get("altitude_m", "height above ground")
    if agl <= 0:
        return None, f"{name} {agl:g} must be > 0 m above ground"
    if agl > MAX_HEIGHT_ABOVE_GROUND_M:
        return None, f"{name} {agl:g} m above ground is not a UAV's height"
    return agl, None


def read_telemetry_table(
    path: Path,
    *,
    ground_elevation_m: float | None = None,
    dem: Path | None = None,
    images_dir: Path | None = None,
) -> Telemetry:
    """Read and check a telemetry CSV (see the module docstring): its rows sorted by time, with
    how the heights above ground were obtained; raises InvalidInputError naming the CSV line of
    every refused value. With ``images_dir``, each image name is placed in it
    (:func:`~c3_matcher_tools.dataset.image_names.place_images`): the rows name their images as
    paths relative to it, none twice."""
    path = Path(path)
    records = _records(path)
    header = _header(records, path)
    cols = _column_map(header, path)
    _check_ground_given(path, cols, ground_elevation_m, dem)
    ground = ground_elevation_sampler(dem) if dem is not None else None
    rows, problems = _read_rows(records, header, _RowRules(cols, ground, ground_elevation_m))
    if not rows and not problems:
        problems.append((1, "no data rows"))
    if images_dir is not None:
        placed, refused = place_images(images_dir, [(r.line, r.image) for r in rows])
        rows = [dataclasses.replace(r, image=placed[r.line]) for r in rows if r.line in placed]
        problems += refused
    rows.sort(key=lambda r: (r.time_s, r.line))
    problems += _repeated_times(rows)
    refuse_lines(path, problems)
    note = radians_note(rows, cols)
    source = _height_source(cols, ground_elevation_m, dem)
    return Telemetry(tuple(rows), source, cols, (note,) if note else ())


def radians_note(rows: Sequence[TelemetryRow], cols: dict[str, str]) -> str | None:
    """A warning when the attitude columns may hold radians: every roll, pitch and yaw of a
    flight of several rows within +-pi, not all zero. Radians always are; degrees only for a
    flight heading within 3 deg of north all along (a straight line north, or a camera whose
    yaw is recorded as 0), which a CSV cannot be told from. So it is a note, never a refusal:
    it fires on every radians file of more than one row and on few degrees files, and it
    refuses none that is right."""
    angles = [a for r in rows for a in (r.roll_deg, r.pitch_deg, r.yaw_deg)]
    if len(rows) < 2 or not any(angles) or max(abs(a) for a in angles) > math.pi:
        return None
    named = ", ".join(repr(cols[k]) for k in ("roll_deg", "pitch_deg", "yaw_deg"))
    return (
        f"every {named} value lies within +-3.1416 (pi): read as degrees, as the telemetry CSV "
        "states attitude; if these are radians, convert them to degrees (x 180/pi), or every "
        "frame is imported as near level and heading north"
    )


def _records(path: Path) -> Iterator[tuple[int, list[str]]]:
    """Each record of the CSV with the line it starts on, blank lines counted and skipped
    after the first; refused when the file is no regular file (a FIFO would wait for a writer
    forever), cannot be read as UTF-8, or holds a record csv cannot read (a field beyond its
    size limit), naming that line."""
    kind = special_kind(path)
    if kind is not None:
        raise InvalidInputError(str(path), f"is {kind}, not a telemetry CSV")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidInputError(str(path), f"unreadable telemetry CSV: {exc}") from None
    reader = csv.reader(io.StringIO(text, newline=""))  # line breaks in quotes kept as they are
    while True:
        start = reader.line_num + 1
        try:
            fields = next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            raise InvalidInputError(str(path), f"line {start}: unreadable record ({exc})") from None
        if fields or start == 1:  # a blank first line is a missing header
            yield start, fields


def _header(records: Iterator[tuple[int, list[str]]], path: Path) -> list[str]:
    """The CSV's first record, its header; refused when there is none."""
    _, header = next(records, (1, []))
    if not header:
        raise InvalidInputError(str(path), "empty telemetry CSV (no header)")
    return header


def _check_ground_given(
    path: Path, cols: dict[str, str], ground_elevation_m: float | None, dem: Path | None
) -> None:
    """Refuse a ground elevation or DEM for a CSV without an altitude above sea level, and
    an altitude above sea level alone without either."""
    has_msl, has_agl = "altitude_msl_m" in cols, "altitude_m" in cols
    given = ground_elevation_m is not None or dem is not None
    if given and not has_msl:
        raise InvalidInputError(
            "--ground-elevation" if dem is None else "--dem",
            f"{path}: column {cols['altitude_m']!r} already is the height above ground; a ground "
            "elevation is for an altitude above sea level column (altitude_msl_m)",
        )
    if has_msl and not has_agl and not given:
        raise InvalidInputError(
            "--ground-elevation",
            f"{path}: column {cols['altitude_msl_m']!r} is an altitude above sea level: give "
            "the ground's (--ground-elevation M, same datum) or a DEM (--dem DEM.tif) to get "
            "the height above ground",
        )


@dataclass(frozen=True)
class _RowRules:
    """How a CSV record becomes a :class:`TelemetryRow`: canonical column -> the header's
    name, and the ground an altitude above sea level is measured from (the DEM's sampler, or
    the given ground elevation)."""

    cols: dict[str, str]
    ground: Callable[[float, float], float | None] | None
    ground_elevation_m: float | None

    @property
    def numeric(self) -> list[str]:
        """The canonical columns given, bar the image name: each must hold a number."""
        return [k for k in (*COLUMNS, *HEIGHT_COLUMNS) if k in self.cols and k != "image"]


def _read_rows(
    records: Iterator[tuple[int, list[str]]], header: list[str], rules: _RowRules
) -> tuple[list[TelemetryRow], list[tuple[int, str]]]:
    """The accepted rows in line order, and (line, why) of each refused one, each named by
    the line its record starts on."""
    rows: list[TelemetryRow] = []
    problems: list[tuple[int, str]] = []
    for n, fields in records:
        rec = dict(zip(header, fields, strict=False))  # a short record lacks the last columns
        extra = len(fields) - len(header)
        row = _too_many(len(rec), extra) if extra > 0 else _row(n, rec, rules)
        if isinstance(row, str):
            problems.append((n, f"line {n}: {row}"))
        else:
            rows.append(row)
    return rows, problems


def _too_many(named: int, extra: int) -> str:
    """Why a record with ``extra`` fields more than the header's ``named`` columns is
    refused: which value went under which column would be a guess (a decimal comma splits a
    number in two)."""
    return f"{named + extra} fields, the header names {named} (a decimal comma?)"


def _row(n: int, rec: dict[str, str], rules: _RowRules) -> TelemetryRow | str:
    """CSV line ``n`` as a row, or why it is refused: its values that are not finite numbers,
    else its image name, else the first value out of range, else its height."""
    cols = rules.cols
    values, bad = _numbers(rec, rules)
    image = str(rec.get(cols["image"]) or "").strip()
    why = "; ".join(bad) if bad else None
    why = why or _image_name_problem(image, cols["image"]) or _row_problem(values, cols)
    if why is not None:
        return why
    height, why = _height(values, cols, rules.ground, rules.ground_elevation_m)
    if height is None:
        return str(why)
    return TelemetryRow(
        n,
        values["time_s"],
        image,
        values["lat"],
        values["lon"],
        height,
        values["roll_deg"],
        values["pitch_deg"],
        values["yaw_deg"],
        values.get("altitude_msl_m"),
    )


def _numbers(rec: dict[str, str], rules: _RowRules) -> tuple[dict[str, float], list[str]]:
    """The record's numeric columns as floats, and what is wrong with each that is not a
    finite number (naming the CSV's column)."""
    values: dict[str, float] = {}
    bad: list[str] = []
    for k in rules.numeric:
        name = rules.cols[k]
        raw = str(rec.get(name) or "").strip()
        try:
            values[k] = float(raw)
        except ValueError:
            bad.append(f"{name} {raw!r} is not a number")
            continue
        if not math.isfinite(values[k]):
            bad.append(f"{name} {raw} is not finite")
    return values, bad


def _image_name_problem(image: str, column: str) -> str | None:
    """Why an image name is refused (empty, or holding a control character such as a line
    break, which no file name meant holds), naming the CSV's column; or None."""
    if not image:
        return f"{column} is empty"
    if _CONTROL.search(image):
        return f"{column} {image!r} holds a line break or another control character"
    return None


def _repeated_times(rows: Sequence[TelemetryRow]) -> list[tuple[int, str]]:
    """(line, why) of each row at the time of the row before it (``rows`` sorted by time), by
    the rule the images placed by their own times follow (:func:`same_times`)."""
    return [
        (rows[b].line, f"lines {rows[a].line} and {rows[b].line}: same time_s {rows[a].time_s}")
        for a, b in same_times([r.time_s for r in rows])
    ]


def _height_source(cols: dict[str, str], ground_elevation_m: float | None, dem: Path | None) -> str:
    """How the heights above ground were obtained, in words."""
    has_msl, has_agl = "altitude_msl_m" in cols, "altitude_m" in cols
    if has_agl and has_msl and (dem is not None or ground_elevation_m is not None):
        return f"column {cols['altitude_m']!r} (checked against {cols['altitude_msl_m']!r})"
    if has_agl:
        return f"column {cols['altitude_m']!r} read as height above ground"
    if dem is not None:
        return f"column {cols['altitude_msl_m']!r} minus the DEM {Path(dem).name}"
    return f"column {cols['altitude_msl_m']!r} minus ground elevation {ground_elevation_m:g} m"
