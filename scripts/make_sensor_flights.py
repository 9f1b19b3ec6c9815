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

import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rasterio

from c3_matcher_tools.dataset.flight import FlightSpec, render_flight
from c3_matcher_tools.dataset.progress import ProgressBar
from c3_matcher_tools.tilestore.build import build_mbtiles

REPO = Path(__file__).resolve().parents[1]
IMAGERY = REPO / "data" / "imagery"
OUT = REPO / "data" / "flights"
NAIP_2020 = IMAGERY / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"
GORINCHEM = IMAGERY / "open_orthophotos" / "test_tiled.tif"
ZURICH = IMAGERY / "open_orthophotos" / "swissimage_zurich_1091-322_00_0p5m.tif"
MANILA = IMAGERY / "open_orthophotos" / "5b90f92da0d7280005fab355_4310.tif"
NAIP_CREDIT = "Imagery: USDA Farm Service Agency, National Agriculture Imagery Program (NAIP)"
CREDITS = {
    NAIP_2020: NAIP_CREDIT,
    GORINCHEM: "Luchtfoto: Beeldmateriaal Nederland (beeldmateriaal.nl), CC BY 4.0",
    ZURICH: "SWISSIMAGE: (c) swisstopo",
    MANILA: "(c) OpenAerialMap contributors, CC BY 4.0",
}
LUMA = (0.299, 0.587, 0.114)


@dataclass(frozen=True)
class SensorFlight:
    """One flight: the frames' orthophoto, how its store is made (``band``: ``rgb``, ``luma``
    or a 1-based band index rendered as grey; ``zoom``) and the flight geometry (metres,
    degrees, px; see ``FlightSpec``)."""

    name: str
    source: Path
    band: str | int
    zoom: int
    height_m: float = 780.0
    orbit_radius_m: float = 450.0
    speed_mps: float = 30.0
    max_tilt_deg: float = 20.0
    candidate_size_px: int = 448
    min_distractor_distance_m: float = 350.0
    max_distractor_nodata: float = 0.35
    absent_share: float = 0.1


FLIGHTS = (
    SensorFlight("naip_nir_tiles", NAIP_2020, 4, 15, speed_mps=60.0),
    SensorFlight(
        "naip_grey_z14",
        NAIP_2020,
        "luma",
        14,
        orbit_radius_m=300.0,
        speed_mps=60.0,
        candidate_size_px=320,
        absent_share=0.0,
    ),
    SensorFlight(
        "gorinchem_z18",
        GORINCHEM,
        "rgb",
        18,
        height_m=45.0,
        orbit_radius_m=40.0,
        speed_mps=10.5,
        max_tilt_deg=10.0,
        candidate_size_px=224,
        min_distractor_distance_m=40.0,
        absent_share=0.0,
    ),
    SensorFlight(
        "zurich_z16",
        ZURICH,
        "rgb",
        16,
        height_m=150.0,
        orbit_radius_m=25.0,
        speed_mps=6.5,
        max_tilt_deg=10.0,
        candidate_size_px=160,
        min_distractor_distance_m=40.0,
        max_distractor_nodata=0.6,
        absent_share=0.0,
    ),
    SensorFlight(
        "manila_grey_z19",
        MANILA,
        "luma",
        19,
        height_m=36.0,
        orbit_radius_m=20.0,
        speed_mps=5.2,
        max_tilt_deg=10.0,
        candidate_size_px=224,
        min_distractor_distance_m=40.0,
        max_distractor_nodata=0.5,
        absent_share=0.0,
    ),
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
    unknown = only - {f.name for f in FLIGHTS}
    if unknown:
        print(f"unknown flight(s): {', '.join(sorted(unknown))}", file=sys.stderr)
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
            build_mbtiles(
                source,
                store,
                zoom=flight.zoom,
                tile_format="jpg",
                jpeg_quality=90,
                attribution=CREDITS[flight.source],
            )
            target = OUT / flight.name
            if target.exists():
                shutil.rmtree(target)
            spec = FlightSpec(
                flight.source,
                store,
                n_frames=12,
                height_m=flight.height_m,
                orbit_radius_m=flight.orbit_radius_m,
                speed_mps=flight.speed_mps,
                max_tilt_deg=flight.max_tilt_deg,
                candidate_size_px=flight.candidate_size_px,
                min_distractor_distance_m=flight.min_distractor_distance_m,
                max_distractor_nodata=flight.max_distractor_nodata,
                absent_share=flight.absent_share,
                seed=seed,
            )
            render_flight(
                spec,
                target,
                name=flight.name,
                attribution=CREDITS[flight.source],
                progress=ProgressBar(flight.name),
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
