"""Regenerate the sensor-differing flights in data/flights/ (committed; deterministic).

Flights where the tile store and the nav frames differ in sensor, band or resolution, not in
date, built from the shipped imagery (data/imagery/, credits in its ATTRIBUTION.md). The frames
are colour (RGB + the renderer's photometric shift); the stores differ:

- ``naip_nir_tiles``: store from the NAIP 2020 near-infrared band alone (a grey image: crops and
  vegetation bright, water black), zoom 15 (3.26 m/px); frames from NAIP 2020 colour.
- ``naip_grey_z14``: store from NAIP 2020 as grey (luminance, ITU-R BT.601) at zoom 14
  (6.5 m/px: 2.5x the frames' 2.6 m nadir GSD, 1.3x the sheet's 5 m); frames NAIP 2020 colour.
- ``gorinchem_z18``: the Dutch orthophoto (0.25 m) as a zoom 18 store (0.37 m/px) against frames
  at 0.15 m nadir GSD (2.5x).
- ``zurich_z16``: SWISSIMAGE Zurich (0.5 m) as a zoom 16 store (1.62 m/px) against frames at
  0.50 m (3.2x).
- ``manila_grey_z19``: the Manila OpenAerialMap orthophoto (0.10 m) as a grey zoom 19 store
  (0.29 m/px) against colour frames at 0.12 m (2.4x).

The three orthophotos cover 200-440 m, so those flights fly a small orbit, use candidate windows
of 160-224 px with distractors 40-60 m away (they may overlap part of the footprint, never its
centre; up to half of a window may lie beyond the orthophoto) and have no frame without its true
tile; naip_grey_z14 has none either (its zoom-14 store is too small for three distractors that
miss the footprint). 12 frames each, 320x240; seeds 31, 32, ... in the order above.

    .venv/bin/python scripts/make_sensor_flights.py            # every flight above
    .venv/bin/python scripts/make_sensor_flights.py NAME...    # only these (re-rendered)
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
from flight_kit import IMAGERY, NAIP, NAIP_CREDIT, build_store, render, unknown_flights

from c3_matcher_tools.dataset.flight_spec import FlightSpec

NAIP_2020 = NAIP / "m_4709963_se_14_1_20200831.tif"
GORINCHEM = IMAGERY / "open_orthophotos" / "test_tiled.tif"
ZURICH = IMAGERY / "open_orthophotos" / "swissimage_zurich_1091-322_00_0p5m.tif"
MANILA = IMAGERY / "open_orthophotos" / "5b90f92da0d7280005fab355_4310.tif"
CREDITS = {
    NAIP_2020: NAIP_CREDIT,
    GORINCHEM: "Luchtfoto: Beeldmateriaal Nederland (beeldmateriaal.nl), CC BY 4.0",
    ZURICH: "SWISSIMAGE: (c) swisstopo",
    MANILA: "(c) OpenAerialMap contributors, CC BY 4.0",
}
LUMA = (0.299, 0.587, 0.114)
N_FRAMES = 12


@dataclass(frozen=True)
class SensorFlight:
    """One flight: how its store is made (``band``: ``rgb``, ``luma`` or a 1-based band index
    rendered as grey; ``zoom``) and its ``spec``: the frames' orthophoto and the flight geometry
    (``FlightSpec``; the store and the seed are set when it is rendered)."""

    name: str
    band: str | int
    zoom: int
    spec: FlightSpec

    @property
    def source(self) -> Path:
        return self.spec.frames_geotiff


def _naip(name: str, band: str | int, zoom: int, **geometry: Any) -> SensorFlight:
    """A flight over NAIP 2020 on the demo flight's orbit, ``geometry`` overriding it."""
    spec = FlightSpec(NAIP_2020, Path(), n_frames=N_FRAMES, speed_mps=60.0, **geometry)
    return SensorFlight(name, band, zoom, spec)


def _small_orbit(
    name: str,
    source: Path,
    band: str,
    zoom: int,
    flight: tuple[float, float, float],
    candidate_size_px: int,
    max_distractor_nodata: float = 0.35,
) -> SensorFlight:
    """A flight over a small orthophoto: ``flight`` = (height, orbit radius in m, speed in m/s),
    tilt up to 10 deg, distractors 40 m away, every frame with its true tile."""
    height_m, orbit_radius_m, speed_mps = flight
    spec = FlightSpec(
        source,
        Path(),
        n_frames=N_FRAMES,
        height_m=height_m,
        orbit_radius_m=orbit_radius_m,
        speed_mps=speed_mps,
        max_tilt_deg=10.0,
        candidate_size_px=candidate_size_px,
        min_distractor_distance_m=40.0,
        max_distractor_nodata=max_distractor_nodata,
        absent_share=0.0,
    )
    return SensorFlight(name, band, zoom, spec)


FLIGHTS = (
    _naip("naip_nir_tiles", 4, 15),
    _naip(
        "naip_grey_z14", "luma", 14, orbit_radius_m=300.0, candidate_size_px=320, absent_share=0.0
    ),
    _small_orbit("gorinchem_z18", GORINCHEM, "rgb", 18, (45.0, 40.0, 10.5), 224),
    _small_orbit("zurich_z16", ZURICH, "rgb", 16, (150.0, 25.0, 6.5), 160, 0.6),
    _small_orbit("manila_grey_z19", MANILA, "luma", 19, (36.0, 20.0, 5.2), 224, 0.5),
)


def grey_geotiff(source: Path, band: str | int, out: Path) -> Path:
    """``source`` as a 3-band grey GeoTIFF (same grid, CRS and nodata): ``band`` ``luma`` is the
    BT.601 luminance of bands 1-3, an int that band alone."""
    with rasterio.open(source) as src:
        profile = src.profile
        if band == "luma":
            rgb = src.read([1, 2, 3]).astype(np.float64)
            grey = np.tensordot(np.asarray(LUMA), rgb, axes=1)
        else:
            grey = src.read(int(band)).astype(np.float64)
    grey_u8 = np.clip(np.rint(grey), 0, 255).astype(np.uint8)
    profile.update(count=3, dtype="uint8", photometric="RGB", compress="deflate")
    profile.pop("jpeg_quality", None)
    with rasterio.open(out, "w", **profile) as dst:
        dst.write(np.stack([grey_u8] * 3))
    return out


def main() -> int:
    only = set(sys.argv[1:])
    if unknown_flights(only, (f.name for f in FLIGHTS)):
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        for seed, flight in enumerate(FLIGHTS, start=31):
            if only and flight.name not in only:
                continue
            source = flight.source
            if flight.band != "rgb":
                kind = "nir" if flight.band == 4 else "grey"
                source = grey_geotiff(
                    flight.source, flight.band, Path(tmp) / f"{flight.source.stem}_{kind}.tif"
                )
            store = Path(tmp) / f"{flight.name}.mbtiles"
            build_store(source, store, flight.zoom, CREDITS[flight.source])
            spec = dataclasses.replace(flight.spec, store=store, seed=seed)
            render(spec, flight.name, CREDITS[flight.source])
    return 0


if __name__ == "__main__":
    sys.exit(main())
