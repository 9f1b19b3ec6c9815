"""Georeferencing without pyproj: GeoTIFF grids, projected metres <-> WGS84 (ground tooling).

Conventions. ORTHO px (u, v) are 0-based with the origin at the centre of the top-left pixel,
(x, y) order. A GeoTIFF's grid maps them to projected metres (E, N) through its pixel scale and
tie point (``PixelIsArea``: the tie point is the top-left pixel's CORNER; ``PixelIsPoint``:
its centre). WORLD px (X, Y) are web-mercator pixels of 256-px slippy tiles at a zoom ``z``
(corner convention: the world spans [0, 256 * 2**z) and pixel index i has its centre at
X = i + 0.5; tile (x, y) covers X in [256 x, 256 (x + 1))).

Projections (:class:`Projection`), all vectorised over numpy arrays, degrees in and out:

- ``utm``: EPSG 326zz / 327zz (WGS84 UTM) and 269zz (NAD83 UTM, treated as WGS84: the datums
  differ by ~1-2 m in North America), exact Kruger series (Karney 2011, n^3 terms: < 1 mm);
- ``web_mercator`` (EPSG 3857/900913) and ``world_mercator`` (EPSG 3395, ellipsoidal), exact;
- ``geographic`` (EPSG 4326): identity;
- ``local_tangent_plane``: any other projected CRS in metres (RD New 28992, LV95 2056, ...):
  the grid is treated as a local plane around a REFERENCE lat/lon given by the user (grid metres
  east/north of the image centre = metres east/north of the reference, equirectangular at the
  reference latitude). It ignores the CRS's scale error and grid convergence (< 0.1 % and < 1
  deg over a few km); it keeps ids, tiles and ground truth mutually consistent, which is all
  the matcher needs, but the lat/lon are only as good as the reference.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Final, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from c3_matcher.arrays import F64
from c3_matcher.errors import InvalidInputError
from c3_matcher.tilestore.geo import TILE_PX, lonlat_to_world_px, world_px_to_lonlat

__all__ = [
    "TILE_PX",
    "GeoGrid",
    "Projection",
    "check_grid_fits_crs",
    "check_pixel_scale",
    "check_source_gsd",
    "geokeys",
    "lonlat_to_world_px",
    "read_geotiff_grid",
    "world_px_to_lonlat",
    "zoom_for_gsd",
]

_A = 6378137.0
_F = 1 / 298.257223563
_E2 = _F * (2 - _F)
_M_PER_DEG = math.pi * _A / 180.0


def _kruger() -> tuple[float, tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
    n = _F / (2 - _F)
    big_a = _A / (1 + n) * (1 + n**2 / 4 + n**4 / 64)
    alpha = (n / 2 - 2 * n**2 / 3 + 5 * n**3 / 16, 13 * n**2 / 48 - 3 * n**3 / 5, 61 * n**3 / 240)
    beta = (n / 2 - 2 * n**2 / 3 + 37 * n**3 / 96, n**2 / 48 + n**3 / 15, 17 * n**3 / 480)
    delta = (2 * n - 2 * n**2 / 3 - 2 * n**3, 7 * n**2 / 3 - 8 * n**3 / 5, 56 * n**3 / 15)
    return big_a, alpha, beta, delta


_KA, _ALPHA, _BETA, _DELTA = _kruger()


@dataclass(frozen=True)
class Projection:
    """A map projection from projected metres (E, N) to WGS84 (lon, lat) degrees and back.

    ``kind``: ``utm`` (``zone``, ``south``), ``web_mercator``, ``world_mercator``,
    ``geographic`` or ``local_tangent_plane`` (``ref_lat``/``ref_lon`` degrees at the grid point
    ``ref_en`` metres)."""

    kind: str
    zone: int = 0
    south: bool = False
    ref_lat: float = 0.0
    ref_lon: float = 0.0
    ref_en: tuple[float, float] = (0.0, 0.0)
    epsg: int = 0

    @classmethod
    def from_epsg(
        cls,
        epsg: int | None,
        *,
        reference: tuple[float, float] | None = None,
        ref_en: tuple[float, float] = (0.0, 0.0),
        source: str | Path = "the grid",
    ) -> Projection:
        """The projection of ``epsg`` (None: a CRS without an EPSG code); a CRS that is not UTM,
        mercator or 4326 and that pyproj cannot convert (no pyproj, no code, a code PROJ does not
        know) needs ``reference`` (lat, lon) degrees of the grid point ``ref_en`` (local tangent
        plane), else it is refused naming ``source``."""
        if epsg is not None and (32601 <= epsg <= 32660 or 32701 <= epsg <= 32760):
            return cls("utm", zone=epsg % 100, south=epsg >= 32701)
        if epsg is not None and 26901 <= epsg <= 26923:
            if pyproj_available():  # NAD83 is not WGS84: the datum shift is pyproj's
                return cls("pyproj", epsg=epsg)
            return cls("utm", zone=epsg - 26900)
        if epsg in (3857, 900913, 3785):
            return cls("web_mercator")
        if epsg == 3395:
            return cls("world_mercator")
        if epsg == 4326:
            return cls("geographic")
        if epsg is not None and _pyproj_knows(epsg):
            return cls("pyproj", epsg=int(epsg))
        if reference is None:
            raise InvalidInputError(
                "geotiff",
                f"{source}: {_unconvertible(epsg)}: give a reference latitude/longitude of the "
                "image centre (--ref-latlon LAT,LON); the grid is then treated as a local tangent "
                "plane around it",
            )
        return cls(
            "local_tangent_plane",
            ref_lat=float(reference[0]),
            ref_lon=float(reference[1]),
            ref_en=(float(ref_en[0]), float(ref_en[1])),
        )

    def describe(self) -> str:
        if self.kind == "utm":
            return f"utm zone {self.zone}{'S' if self.south else 'N'} (exact, Kruger series)"
        if self.kind == "local_tangent_plane":
            return (
                f"local tangent plane at lat {self.ref_lat:.7f}, lon {self.ref_lon:.7f} "
                f"(grid E {self.ref_en[0]:.2f}, N {self.ref_en[1]:.2f})"
            )
        if self.kind == "pyproj":
            return f"EPSG:{self.epsg} (exact, pyproj)"
        return f"{self.kind} (exact)"

    def to_dict(self) -> dict[str, Any]:
        """Every field, in order; ``epsg`` only when set."""
        data = {**asdict(self), "ref_en": list(self.ref_en)}
        if not self.epsg:
            del data["epsg"]
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Projection:
        return cls(
            str(data["kind"]),
            int(data.get("zone", 0)),
            bool(data.get("south", False)),
            float(data.get("ref_lat", 0.0)),
            float(data.get("ref_lon", 0.0)),
            (float(data.get("ref_en", (0, 0))[0]), float(data.get("ref_en", (0, 0))[1])),
            int(data.get("epsg", 0)),
        )

    def __post_init__(self) -> None:
        if self.kind not in _FORMULAS:
            raise InvalidInputError(
                "projection.kind",
                f"unknown projection {self.kind!r}, expected one of: {', '.join(_FORMULAS)}",
            )

    def to_lonlat(self, e: ArrayLike, n: ArrayLike) -> tuple[F64, F64]:
        """Projected metres -> (lon, lat) degrees."""
        e_a, n_a = np.asarray(e, dtype=np.float64), np.asarray(n, dtype=np.float64)
        return _FORMULAS[self.kind].inverse(self, e_a, n_a)

    def from_lonlat(self, lon: ArrayLike, lat: ArrayLike) -> tuple[F64, F64]:
        """(lon, lat) degrees -> projected metres."""
        lo, la = np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)
        return _FORMULAS[self.kind].forward(self, lo, la)


_Formula = Callable[[Projection, F64, F64], tuple[F64, F64]]


class _Formulas(NamedTuple):
    """One projection kind's pair: ``forward`` (lon, lat) degrees -> metres, ``inverse``."""

    forward: _Formula
    inverse: _Formula


def _utm_lon0(p: Projection) -> float:
    return math.radians(-183.0 + 6.0 * p.zone)


def _utm_forward(p: Projection, lon: F64, lat: F64) -> tuple[F64, F64]:
    k0, n = 0.9996, _F / (2 - _F)
    phi, lam = np.radians(lat), np.radians(lon) - _utm_lon0(p)
    c = 2 * math.sqrt(n) / (1 + n)
    t = np.sinh(np.arctanh(np.sin(phi)) - c * np.arctanh(c * np.sin(phi)))
    xi_p = np.arctan2(t, np.cos(lam))
    eta_p = np.arctanh(np.sin(lam) / np.sqrt(1 + t * t))
    xi, eta = xi_p.copy(), eta_p.copy()
    for j, a in enumerate(_ALPHA, start=1):
        xi += a * np.sin(2 * j * xi_p) * np.cosh(2 * j * eta_p)
        eta += a * np.cos(2 * j * xi_p) * np.sinh(2 * j * eta_p)
    e = 500_000.0 + k0 * _KA * eta
    north = k0 * _KA * xi + (10_000_000.0 if p.south else 0.0)
    return e, north


def _utm_inverse(p: Projection, e: F64, north: F64) -> tuple[F64, F64]:
    k0 = 0.9996
    xi = (north - (10_000_000.0 if p.south else 0.0)) / (k0 * _KA)
    eta = (e - 500_000.0) / (k0 * _KA)
    xi_p, eta_p = xi.copy(), eta.copy()
    for j, b in enumerate(_BETA, start=1):
        xi_p -= b * np.sin(2 * j * xi) * np.cosh(2 * j * eta)
        eta_p -= b * np.cos(2 * j * xi) * np.sinh(2 * j * eta)
    chi = np.arcsin(np.sin(xi_p) / np.cosh(eta_p))
    phi = chi.copy()
    for j, d in enumerate(_DELTA, start=1):
        phi += d * np.sin(2 * j * chi)
    lam = np.arctan2(np.sinh(eta_p), np.cos(xi_p))
    return np.degrees(_utm_lon0(p) + lam), np.degrees(phi)


def _mercator_forward(_p: Projection, lon: F64, lat: F64, *, ellipsoidal: bool) -> tuple[F64, F64]:
    phi = np.radians(lat)
    y = np.log(np.tan(np.pi / 4 + phi / 2))
    if ellipsoidal:  # world mercator
        e1 = math.sqrt(_E2)
        es = e1 * np.sin(phi)
        y = y + (e1 / 2) * np.log((1 - es) / (1 + es))
    return _A * np.radians(lon), _A * y


def _mercator_inverse(_p: Projection, e: F64, n: F64, *, ellipsoidal: bool) -> tuple[F64, F64]:
    lon = np.degrees(e / _A)
    t = np.exp(-n / _A)
    phi = np.pi / 2 - 2 * np.arctan(t)
    if ellipsoidal:  # world mercator: fixed-point iteration on the latitude
        e1 = math.sqrt(_E2)
        for _ in range(12):
            es = e1 * np.sin(phi)
            phi = np.pi / 2 - 2 * np.arctan(t * ((1 - es) / (1 + es)) ** (e1 / 2))
    return lon, np.degrees(phi)


def _identity(_p: Projection, a: F64, b: F64) -> tuple[F64, F64]:
    return a.copy(), b.copy()


def _pyproj_forward(p: Projection, lon: F64, lat: F64) -> tuple[F64, F64]:
    e, n = _transformer(p.epsg, inverse=False).transform(lon, lat)
    return np.asarray(e, np.float64), np.asarray(n, np.float64)


def _pyproj_inverse(p: Projection, e: F64, n: F64) -> tuple[F64, F64]:
    lon, lat = _transformer(p.epsg, inverse=True).transform(e, n)
    return np.asarray(lon, np.float64), np.asarray(lat, np.float64)


def _tangent_plane_forward(p: Projection, lon: F64, lat: F64) -> tuple[F64, F64]:
    n = p.ref_en[1] + (lat - p.ref_lat) * _M_PER_DEG
    e = p.ref_en[0] + (lon - p.ref_lon) * (_M_PER_DEG * math.cos(math.radians(p.ref_lat)))
    return e, n


def _tangent_plane_inverse(p: Projection, e: F64, n: F64) -> tuple[F64, F64]:
    lat = p.ref_lat + (n - p.ref_en[1]) / _M_PER_DEG
    lon = p.ref_lon + (e - p.ref_en[0]) / (_M_PER_DEG * math.cos(math.radians(p.ref_lat)))
    return lon, lat


_FORMULAS: Final[Mapping[str, _Formulas]] = {
    "utm": _Formulas(_utm_forward, _utm_inverse),
    "web_mercator": _Formulas(
        functools.partial(_mercator_forward, ellipsoidal=False),
        functools.partial(_mercator_inverse, ellipsoidal=False),
    ),
    "world_mercator": _Formulas(
        functools.partial(_mercator_forward, ellipsoidal=True),
        functools.partial(_mercator_inverse, ellipsoidal=True),
    ),
    "geographic": _Formulas(_identity, _identity),
    "pyproj": _Formulas(_pyproj_forward, _pyproj_inverse),
    "local_tangent_plane": _Formulas(_tangent_plane_forward, _tangent_plane_inverse),
}
"""Each projection kind's formulas (the module docstring); a ``Projection`` of a kind not here is
refused. ``describe`` and the grid range check add what a kind needs beyond its formulas."""


@dataclass(frozen=True)
class GeoGrid:
    """A north-up GeoTIFF grid: ORTHO px (u, v) -> projected metres
    ``E = origin_e + (u + 0.5) * scale_x``, ``N = origin_n - (v + 0.5) * scale_y`` where
    (origin_e, origin_n) is the top-left pixel's corner; ``projection`` converts to WGS84;
    ``size`` (w, h) px; ``epsg`` the file's projected/geographic CRS code (None if absent)."""

    origin_e: float
    origin_n: float
    scale_x: float
    scale_y: float
    size: tuple[int, int]
    epsg: int | None
    projection: Projection

    def px_to_lonlat(self, pts: ArrayLike) -> F64:
        """(N, 2) ORTHO px -> (N, 2) (lon, lat) degrees."""
        p = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        e = self.origin_e + (p[:, 0] + 0.5) * self.scale_x
        n = self.origin_n - (p[:, 1] + 0.5) * self.scale_y
        lon, lat = self.projection.to_lonlat(e, n)
        return np.stack([lon, lat], axis=1)

    def lonlat_to_px(self, lonlat: ArrayLike) -> F64:
        """(N, 2) (lon, lat) degrees -> (N, 2) ORTHO px."""
        q = np.asarray(lonlat, dtype=np.float64).reshape(-1, 2)
        e, n = self.projection.from_lonlat(q[:, 0], q[:, 1])
        return np.stack(
            [(e - self.origin_e) / self.scale_x - 0.5, (self.origin_n - n) / self.scale_y - 0.5],
            axis=1,
        )

    def centre_lonlat(self) -> tuple[float, float]:
        w, h = self.size
        lon, lat = self.px_to_lonlat([[(w - 1) / 2, (h - 1) / 2]])[0]
        return float(lon), float(lat)


def pyproj_available() -> bool:
    """The ``geo`` extra is installed (pyproj: any EPSG grid, exact) and not switched off by
    ``C3_MATCHER_TOOLS_NO_PYPROJ=1`` (the hand-written fallback, for comparison)."""
    import importlib.util
    import os

    if os.environ.get("C3_MATCHER_TOOLS_NO_PYPROJ") == "1":
        return False
    return importlib.util.find_spec("pyproj") is not None


def _pyproj_knows(epsg: int) -> bool:
    """pyproj is available (:func:`pyproj_available`) and its PROJ database holds ``epsg``."""
    return pyproj_available() and _proj_database_has(epsg)


@functools.lru_cache(maxsize=32)
def _proj_database_has(epsg: int) -> bool:
    """PROJ's database holds EPSG ``epsg`` (asked once per code)."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        CRS.from_epsg(epsg)
    except CRSError:
        return False
    return True


def _unconvertible(epsg: int | None) -> str:
    """Why pyproj cannot convert the CRS ``epsg`` (None: no EPSG code, or one GDAL could not
    resolve) to WGS84."""
    if epsg is None:
        return "its CRS has no EPSG code that PROJ knows, so it cannot be converted to WGS84"
    if not pyproj_available():
        return f"EPSG:{epsg} cannot be converted to WGS84 without pyproj"
    return f"EPSG:{epsg} is not a CRS that PROJ knows, so it cannot be converted to WGS84"


@functools.lru_cache(maxsize=32)
def _transformer(epsg: int, *, inverse: bool) -> Any:
    from pyproj import Transformer

    if inverse:
        return Transformer.from_crs(f"EPSG:{epsg}", "EPSG:4326", always_xy=True)
    return Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)


def geokeys(directory: Any) -> dict[int, Any]:
    """The GeoKeyDirectory (tag 34735) of a GeoTIFF as {key id: value} (inline values)."""
    values = [int(v) for v in directory]
    keys: dict[int, Any] = {}
    for i in range(values[3]):
        key_id, location, _count, value = values[4 + 4 * i : 8 + 4 * i]
        if location == 0:
            keys[key_id] = value
    return keys


def read_geotiff_grid(path: str | Path, *, reference: tuple[float, float] | None = None) -> GeoGrid:
    """Read the north-up grid of a GeoTIFF (ModelPixelScale + ModelTiepoint + GeoKeys) with
    ``tifffile``; ``reference`` (lat, lon) of the image centre is needed for CRSs other than
    UTM / mercator / 4326 (see the module docstring). Rotated grids (ModelTransformation) are
    refused."""
    import tifffile

    p = Path(path)
    if not p.is_file():
        raise InvalidInputError("geotiff", f"no such file: {p}")
    try:
        with tifffile.TiffFile(str(p)) as tif:
            page = tif.pages.first
            tags = {c: page.tags[c].value for c in (33550, 33922, 34735) if c in page.tags}
            w, h = int(page.imagewidth), int(page.imagelength)
    except Exception as exc:  # tifffile raises many kinds on a non-TIFF
        raise InvalidInputError(
            "geotiff", f"{p}: no georeference (not a TIFF: {' '.join(str(exc).split())})"
        ) from exc
    if 33550 not in tags or 33922 not in tags:
        raise InvalidInputError(
            "geotiff",
            f"{p}: no georeference (no ModelPixelScale/ModelTiepoint tags: not a north-up GeoTIFF)",
        )
    sx, sy = float(tags[33550][0]), float(tags[33550][1])
    check_pixel_scale(sx, sy, p)
    tie = [float(t) for t in tags[33922][:6]]
    keys = geokeys(tags[34735]) if 34735 in tags else {}
    point = keys.get(1025) == 2  # RasterPixelIsPoint: the tie point is a pixel centre
    i0, j0, e0, n0 = tie[0], tie[1], tie[3], tie[4]
    shift = 0.5 if point else 0.0
    origin_e = e0 - (i0 + shift) * sx
    origin_n = n0 + (j0 + shift) * sy
    epsg = keys.get(3072) or keys.get(2048)
    centre_en = (origin_e + w / 2 * sx, origin_n - h / 2 * sy)
    projection = Projection.from_epsg(
        None if epsg is None else int(epsg), reference=reference, ref_en=centre_en, source=p
    )
    grid = GeoGrid(origin_e, origin_n, sx, sy, (w, h), epsg, projection)
    check_grid_fits_crs(grid, p)
    return grid


def check_pixel_scale(scale_x: float, scale_y: float, source: str | Path) -> None:
    """Refuse a pixel size that is not finite and > 0 on both axes (E to the right, N up): a
    negative one flips the grid (not north-up), zero or NaN is no grid at all."""
    if not all(math.isfinite(s) and s > 0 for s in (scale_x, scale_y)):
        raise InvalidInputError(
            "geotiff",
            f"{source}: not a north-up grid: its pixel size {scale_x:g} x {scale_y:g} (E x N) "
            "must be finite and > 0 on both axes",
        )


_MERCATOR_MAX_M = 20_048_966.2  # web-mercator northing at lat 85.06 deg (the tiles' limit)


def _crs_bounds(projection: Projection) -> tuple[str, float, float, float, float] | None:
    """(what the coordinates are, E min, E max, N min, N max) a grid of ``projection`` can hold,
    or None when there is no fixed range (local tangent plane, pyproj: checked in lon/lat)."""
    if projection.kind == "geographic":
        return "degrees (lon -180..180, lat -90..90)", -180.0, 180.0, -90.0, 90.0
    if projection.kind == "utm":
        return "UTM metres (E 0..1,000,000, N 0..10,000,000)", 0.0, 1e6, 0.0, 1e7
    if projection.kind in ("web_mercator", "world_mercator"):
        m = _MERCATOR_MAX_M
        return "mercator metres (|E|, |N| <= 20,048,966)", -m, m, -m, m
    return None


def check_grid_fits_crs(grid: GeoGrid, source: str | Path) -> None:
    """Refuse a grid whose coordinates cannot be its CRS's (metres labelled degrees, a wrong
    EPSG code, a missing scale): its corners must lie in the CRS's range (degrees: lon -180..180,
    lat -90..90; UTM: E 0..1e6 m, N 0..1e7 m; mercator: within the world) and convert to finite
    lon/lat (pyproj CRSs: within 2 degrees of the CRS's area of use)."""
    w, h = grid.size
    e0, e1 = grid.origin_e, grid.origin_e + w * grid.scale_x
    n0, n1 = grid.origin_n - h * grid.scale_y, grid.origin_n
    label = f"EPSG:{grid.epsg}" if grid.epsg else "its CRS"
    extent = f"E {e0:,.2f}..{e1:,.2f}, N {n0:,.2f}..{n1:,.2f}"
    bounds = _crs_bounds(grid.projection)
    if bounds is not None:
        what, e_lo, e_hi, n_lo, n_hi = bounds
        if not (e_lo <= e0 and e1 <= e_hi and n_lo <= n0 and n1 <= n_hi):
            raise InvalidInputError(
                "geotiff",
                f"{source}: coordinates ({extent}) do not fit {label}, whose coordinates are "
                f"{what}: is the CRS right?",
            )
    with np.errstate(all="ignore"):
        corners = grid.px_to_lonlat(
            [[-0.5, -0.5], [w - 0.5, -0.5], [-0.5, h - 0.5], [w - 0.5, h - 0.5]]
        )
    lon, lat = corners[:, 0], corners[:, 1]
    ok = bool(np.isfinite(corners).all() and (np.abs(lon) <= 180).all())
    ok = ok and bool((np.abs(lat) <= 90).all())
    if ok and grid.projection.kind == "pyproj":
        area = _area_of_use(grid.projection.epsg)
        if area is not None:
            west, south, east, north = area
            ok = bool(
                lon.min() >= west - 2 and lon.max() <= east + 2
                and lat.min() >= south - 2 and lat.max() <= north + 2
            )  # fmt: skip
            if not ok:
                raise InvalidInputError(
                    "geotiff",
                    f"{source}: coordinates ({extent}) fall at lon {lon.min():.3f}..{lon.max():.3f}"
                    f", lat {lat.min():.3f}..{lat.max():.3f}, outside {label}'s area of use (lon "
                    f"{west}..{east}, lat {south}..{north}): is the CRS right?",
                )
    if not ok:
        raise InvalidInputError(
            "geotiff",
            f"{source}: coordinates ({extent}) do not convert to a valid latitude/longitude "
            f"in {label}: is the CRS right?",
        )


#: plausible ground GSD of an orthophoto, m/px (a grid outside it has the wrong units)
GSD_RANGE_M = (0.001, 10_000.0)


def check_source_gsd(gsd_m: float, source: str | Path) -> None:
    """Refuse a ground GSD outside :data:`GSD_RANGE_M` (degrees labelled metres and the like)."""
    lo, hi = GSD_RANGE_M
    if not (math.isfinite(gsd_m) and lo <= gsd_m <= hi):
        raise InvalidInputError(
            "geotiff",
            f"{source}: a pixel of {gsd_m:.6g} m on the ground is not plausible for an "
            f"orthophoto ({lo} to {hi:,.0f} m): are the CRS and its units right?",
        )


def _area_of_use(epsg: int) -> tuple[float, float, float, float] | None:
    """(west, south, east, north) degrees where pyproj says EPSG ``epsg`` is used, or None."""
    from pyproj import CRS

    area = CRS.from_epsg(epsg).area_of_use
    return None if area is None else (area.west, area.south, area.east, area.north)


def zoom_for_gsd(gsd_m: float, lat_deg: float) -> int:
    """The default web-mercator zoom for a source of ground GSD ``gsd_m`` at ``lat_deg``: the
    coarsest zoom whose ground GSD is at most the source's (x 1.05, so a source a hair coarser
    than a zoom is not upsampled needlessly), i.e. no source detail is thrown away. (The zoom
    nearest the GSD on a log scale, the old default, picked zoom 14 at 6.5 m/px for the 5 m NAIP
    sheet: a store of 12 tiles on which ``dataset render`` finds no distractors.)"""
    z0 = 2 * math.pi * _A / TILE_PX * math.cos(math.radians(lat_deg))
    return max(0, min(30, math.ceil(math.log2(z0 / (gsd_m * 1.05)))))
