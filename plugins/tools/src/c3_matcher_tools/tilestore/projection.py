"""Map projections between projected metres (E, N) and WGS84 lon/lat degrees (ground tooling)."""

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
from c3_matcher_tools.extras import install_line, not_installed
from c3_matcher_tools.geodesy import (
    MERCATOR_EPSG,
    WGS84_A,
    WGS84_E2,
    WGS84_F,
    mercator_latitude_deg,
    pyproj_available,
)

__all__ = ["Projection", "pyproj_available", "wrap_lon"]

_M_PER_DEG = math.pi * WGS84_A / 180.0


def wrap_lon(lon: ArrayLike, around: float = 0.0) -> F64:
    """Longitudes (degrees) moved by whole turns to within 180 deg of ``around``: by default
    into [-180, 180] (a grid across 180 deg converts to longitudes on both sides of it); around
    a grid's centre, its longitudes read as one stretch (179.9 .. 180.1). A longitude already
    there is returned bit for bit."""
    a = np.asarray(lon, dtype=np.float64)
    return np.asarray(a - 360.0 * np.round((a - around) / 360.0), dtype=np.float64)


def _kruger() -> tuple[float, tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
    n = WGS84_F / (2 - WGS84_F)
    big_a = WGS84_A / (1 + n) * (1 + n**2 / 4 + n**4 / 64)
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
    ``ref_en`` metres).

    The projections, all vectorised over numpy arrays, degrees in and out:

    - ``utm``: EPSG 326zz / 327zz (WGS84 UTM) and 269zz (NAD83 UTM, treated as WGS84: the datums
      differ by ~1-2 m in North America), exact Kruger series (Karney 2011, n^3 terms: < 1 mm);
    - ``web_mercator`` (EPSG 3857/900913) and ``world_mercator`` (EPSG 3395, ellipsoidal), exact;
    - ``geographic`` (EPSG 4326): identity;
    - ``local_tangent_plane``: any other projected CRS in metres (RD New 28992, LV95 2056, ...):
      the grid is treated as a local plane around a REFERENCE lat/lon given by the user (grid
      metres east/north of the image centre = metres east/north of the reference, equirectangular
      at the reference latitude). It ignores the CRS's scale error and grid convergence (< 0.1 %
      and < 1 deg over a few km); it keeps ids, tiles and ground truth mutually consistent, which
      is all the matcher needs, but the lat/lon are only as good as the reference.

    UTM and the tangent plane are periodic in longitude: a grid across 180 deg converts to
    longitudes in [-180, 180] on both sides of it, and back (:func:`wrap_lon`)."""

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
        if epsg in MERCATOR_EPSG:
            return cls("world_mercator" if MERCATOR_EPSG[epsg] else "web_mercator")
        if epsg == 4326:
            return cls("geographic")
        if epsg is not None and _pyproj_knows(epsg):
            return cls("pyproj", epsg=int(epsg))
        if reference is None:
            raise InvalidInputError("geotiff", f"{source}: {_unconvertible(epsg)}")
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
    k0, n = 0.9996, WGS84_F / (2 - WGS84_F)
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
    return wrap_lon(np.degrees(_utm_lon0(p) + lam)), np.degrees(phi)


def _mercator_forward(_p: Projection, lon: F64, lat: F64, *, ellipsoidal: bool) -> tuple[F64, F64]:
    phi = np.radians(lat)
    y = np.log(np.tan(np.pi / 4 + phi / 2))
    if ellipsoidal:  # world mercator
        e1 = math.sqrt(WGS84_E2)
        es = e1 * np.sin(phi)
        y = y + (e1 / 2) * np.log((1 - es) / (1 + es))
    return WGS84_A * np.radians(lon), WGS84_A * y


def _mercator_inverse(_p: Projection, e: F64, n: F64, *, ellipsoidal: bool) -> tuple[F64, F64]:
    return np.degrees(e / WGS84_A), mercator_latitude_deg(n, ellipsoidal=ellipsoidal)


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
    east_deg = wrap_lon(lon - p.ref_lon)  # across 180 deg: the short way round
    e = p.ref_en[0] + east_deg * (_M_PER_DEG * math.cos(math.radians(p.ref_lat)))
    return e, n


def _tangent_plane_inverse(p: Projection, e: F64, n: F64) -> tuple[F64, F64]:
    lat = p.ref_lat + (n - p.ref_en[1]) / _M_PER_DEG
    lon = p.ref_lon + (e - p.ref_en[0]) / (_M_PER_DEG * math.cos(math.radians(p.ref_lat)))
    return wrap_lon(lon), lat


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
"""Each projection kind's formulas (:class:`Projection`); a ``Projection`` of a kind not here is
refused. ``describe`` and the grid range check
(:func:`~c3_matcher_tools.tilestore.geo.check_grid_fits_crs`) add what a kind needs beyond its
formulas."""


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


_GIVE_REFERENCE = (
    "give a reference latitude/longitude of the image centre (--ref-latlon LAT,LON); the grid "
    "is then treated as a local tangent plane around it"
)


def _unconvertible(epsg: int | None) -> str:
    """Why pyproj cannot convert the CRS ``epsg`` (None: no EPSG code, or one GDAL could not
    resolve) to WGS84, and what to do: install the geo extra where that may convert it (pyproj;
    rasterio, which reads a CRS given by its parameters), else give a reference point."""
    if epsg is None:
        why = "its CRS has no EPSG code that PROJ knows, so it cannot be converted to WGS84"
        if not_installed("rasterio"):  # GDAL may find the EPSG CRS its parameters describe
            return (
                f"{why} here: install the geo extra ({install_line('geo')}), which reads a CRS "
                f"given by its parameters, or {_GIVE_REFERENCE}"
            )
    elif pyproj_available():
        why = f"EPSG:{epsg} is not a CRS that PROJ knows, so it cannot be converted to WGS84"
    elif not_installed("pyproj"):
        return (
            f"EPSG:{epsg} cannot be converted to WGS84 without pyproj: install the geo extra "
            f"({install_line('geo')}) for the exact conversion, or {_GIVE_REFERENCE}"
        )
    else:
        why = (
            f"EPSG:{epsg} cannot be converted to WGS84 without pyproj (switched off: "
            "C3_MATCHER_TOOLS_NO_PYPROJ=1)"
        )
    return f"{why}: {_GIVE_REFERENCE}"


@functools.lru_cache(maxsize=32)
def _transformer(epsg: int, *, inverse: bool) -> Any:
    from pyproj import Transformer

    if inverse:
        return Transformer.from_crs(f"EPSG:{epsg}", "EPSG:4326", always_xy=True)
    return Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)
