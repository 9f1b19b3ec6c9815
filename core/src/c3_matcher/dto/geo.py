"""Where and how the vehicle is: the composite tile id and the attitude.

Tile centres are WGS84 degrees; angles are radians, aerospace Z-Y-X (yaw, pitch, roll) of the
NED body frame, yaw from true north.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from c3_matcher import _validate as v
from c3_matcher.errors import InvalidInputError

WEB_MERCATOR_EQUATOR_M_PER_PX = 156543.03392804097  # 256-px tiles, zoom 0


@dataclass(frozen=True, slots=True)
class TileId:
    """Composite tile id (zoomLevel, lat, lon): the tile centre, WGS84 degrees."""

    zoom: int
    lat: float
    lon: float

    def __post_init__(self) -> None:
        if isinstance(self.zoom, bool) or not isinstance(self.zoom, int):
            raise InvalidInputError("tile_id.zoom", f"expected an int, got {self.zoom!r}")
        v.require(0 <= self.zoom <= 30, "tile_id.zoom", f"must be in [0, 30], got {self.zoom}")
        object.__setattr__(self, "lat", v.finite_float(self.lat, "tile_id.lat", low=-90, high=90))
        object.__setattr__(self, "lon", v.finite_float(self.lon, "tile_id.lon", low=-180, high=180))

    @classmethod
    def parse(cls, text: str) -> TileId:
        """Parse ``"ZOOM,LAT,LON"`` (the CLI form)."""
        parts = text.split(",")
        if len(parts) != 3:
            raise InvalidInputError("tile_id", f"expected ZOOM,LAT,LON, got {text!r}")
        try:
            return cls(int(parts[0]), float(parts[1]), float(parts[2]))
        except ValueError as exc:
            raise InvalidInputError("tile_id", f"cannot parse {text!r}: {exc}") from exc

    def web_mercator_gsd_m(self, tile_size_px: int = 256) -> float:
        """Ground sample distance (m/px) of a web-mercator tile of this zoom at this latitude."""
        scale = 256.0 / tile_size_px
        return (
            WEB_MERCATOR_EQUATOR_M_PER_PX
            * scale
            * math.cos(math.radians(self.lat))
            / (2**self.zoom)
        )

    def as_list(self) -> list[float | int]:
        return [self.zoom, self.lat, self.lon]

    def __str__(self) -> str:
        return f"{self.zoom},{self.lat:.7f},{self.lon:.7f}"


@dataclass(frozen=True, slots=True)
class Attitude:
    """Vehicle attitude in radians: Z-Y-X (yaw, pitch, roll), NED body frame, yaw from north."""

    roll: float
    pitch: float
    yaw: float

    def __post_init__(self) -> None:
        half_pi = math.pi / 2
        for name, bound in (("roll", half_pi), ("pitch", half_pi), ("yaw", 2 * math.pi)):
            value = v.finite_float(getattr(self, name), f"attitude.{name}", low=-bound, high=bound)
            object.__setattr__(self, name, value)

    @classmethod
    def from_degrees(cls, roll: float, pitch: float, yaw: float) -> Attitude:
        """The attitude of angles in degrees, refused in degrees (the unit they were given in):
        roll and pitch in [-90, 90], yaw in [-360, 360]."""
        for name, value, bound in (
            ("roll", roll, 90.0),
            ("pitch", pitch, 90.0),
            ("yaw", yaw, 360.0),
        ):
            v.finite_float(value, f"attitude.{name}_deg", low=-bound, high=bound)
        return cls(math.radians(roll), math.radians(pitch), math.radians(yaw))
