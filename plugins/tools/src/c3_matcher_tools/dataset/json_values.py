"""The checks each value of a dataset's JSON files passes (``dataset.json``, each record of
``frames.jsonl``), every one an InvalidInputError naming the key at fault. The files are
parsed with core's ``loads_json`` (a document nested too deep is bad input there)."""

from __future__ import annotations

import math
from typing import Any

from c3_matcher.errors import InvalidInputError

__all__ = [
    "json_integer",
    "json_number",
    "json_object",
    "json_text",
    "pose_values",
    "telemetry_values",
]


def json_object(value: object, field: str) -> dict[str, Any]:
    """``value`` when it is a JSON object, else InvalidInputError naming ``field``."""
    if not isinstance(value, dict):
        raise InvalidInputError(field, f"expected a JSON object, got {type(value).__name__}")
    return value


def json_number(value: object, field: str, low: float = -math.inf, high: float = math.inf) -> float:
    """``value`` when it is a finite JSON number in [low, high], as a float, else
    InvalidInputError naming ``field``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InvalidInputError(field, f"expected a number, got {value!r}")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond a float's range
        number = math.inf
    if not math.isfinite(number):
        raise InvalidInputError(field, f"must be finite, got {value!r}")
    if not low <= number <= high:
        raise InvalidInputError(field, f"must be in [{low:g}, {high:g}], got {value!r}")
    return number


def json_integer(value: object, field: str, low: int, high: int) -> int:
    """``value`` when it is a JSON integer in [low, high], else InvalidInputError naming
    ``field``."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise InvalidInputError(field, f"expected an integer, got {value!r}")
    if not low <= value <= high:
        raise InvalidInputError(field, f"must be in [{low}, {high}], got {value}")
    return value


def json_text(value: object, field: str) -> str:
    """``value`` when it is a non-empty JSON string, else InvalidInputError naming ``field``."""
    if not isinstance(value, str) or not value:
        raise InvalidInputError(field, f"expected a non-empty string, got {value!r}")
    return value


def _degrees(
    values: dict[str, Any], field: str, pairs: tuple[tuple[str, str], ...]
) -> dict[str, Any]:
    """A copy of ``values`` whose (latitude, longitude) keys of ``pairs``, where present, are
    checked as WGS84 degrees; InvalidInputError names ``field`` and the key."""
    for lat, lon in pairs:
        if lat in values:
            json_number(values[lat], f"{field}.{lat}", -90.0, 90.0)
        if lon in values:
            json_number(values[lon], f"{field}.{lon}", -180.0, 180.0)
    return dict(values)


def telemetry_values(value: object) -> dict[str, Any]:
    """A record's ``telemetry``, the values replay and its report read checked: the vehicle's
    position, where the frame looks and the stated GNSS accuracy (m)."""
    telemetry = _degrees(
        json_object(value, "telemetry"), "telemetry", (("lat", "lon"), ("look_lat", "look_lon"))
    )
    if telemetry.get("gnss_accuracy_m") is not None:
        json_number(telemetry["gnss_accuracy_m"], "telemetry.gnss_accuracy_m", low=0.0)
    return telemetry


def pose_values(value: object) -> dict[str, Any]:
    """A record's ``pose``, its positions checked (scoring reads the nadir)."""
    pairs = (("nadir_lat", "nadir_lon"), ("footprint_centre_lat", "footprint_centre_lon"))
    return _degrees(json_object(value, "pose"), "pose", pairs)
