"""What the flight-regenerating scripts (``make_demo_flight.py``, ``make_cross_season_flights.py``,
``make_sensor_flights.py``) share: where the imagery and the flights are, the NAIP credit, how a
store is cut (JPEG 90 MBTiles) and how a flight is (re)rendered into ``data/flights/<name>``.
Imported by those scripts (run as ``.venv/bin/python scripts/<script>.py``), not installed."""

from __future__ import annotations

import shutil
import sys
from collections.abc import Iterable
from pathlib import Path

from c3_matcher_tools.dataset.flight import render_flight
from c3_matcher_tools.dataset.flight_spec import FlightSpec
from c3_matcher_tools.dataset.progress import ProgressBar
from c3_matcher_tools.tilestore.build import BuildReport, build_mbtiles

REPO = Path(__file__).resolve().parents[1]
IMAGERY = REPO / "data" / "imagery"
NAIP = IMAGERY / "naip_timeseries"
OUT = REPO / "data" / "flights"
NAIP_CREDIT = "Imagery: USDA Farm Service Agency, National Agriculture Imagery Program (NAIP)"


def unknown_flights(only: Iterable[str], names: Iterable[str]) -> bool:
    """Say on stderr which of the requested flight names ``only`` are not among ``names``;
    True when any is not (the script then exits 2)."""
    unknown = set(only) - set(names)
    if unknown:
        print(f"unknown flight(s): {', '.join(sorted(unknown))}", file=sys.stderr)
    return bool(unknown)


def build_store(
    geotiff: Path, out: Path, zoom: int, credit: str, *, progress: ProgressBar | None = None
) -> BuildReport:
    """Cut ``geotiff`` into a zoom-``zoom`` MBTiles store of JPEG (quality 90) tiles at ``out``."""
    return build_mbtiles(
        geotiff,
        out,
        zoom=zoom,
        tile_format="jpg",
        jpeg_quality=90,
        attribution=credit,
        progress=progress,
    )


def render(spec: FlightSpec, name: str, credit: str) -> None:
    """Render ``spec`` into ``data/flights/<name>``, replacing what is there."""
    target = OUT / name
    if target.exists():
        shutil.rmtree(target)
    render_flight(spec, target, name=name, attribution=credit, progress=ProgressBar(name))
