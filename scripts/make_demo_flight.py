"""Regenerate the built-in flight datasets in data/flights/ (committed; this documents how they
were made). Deterministic: the same code and imagery give the same files.

- ``naip_demo``: the demo flight (CI's replay + eval). Tiles: NAIP 2020 (Aug 2020) cut into a
  zoom-15 MBTiles store (3.26 m/px, JPEG); frames rendered from the same NAIP 2020 image with a
  photometric domain shift; 30 frames on a 450 m orbit at 780 m above ground, tilt up to 20 deg,
  every yaw, lens distortion, 3 frames without their true tile.
- ``naip_cross_date``: the real cross-date case. Same store and flight, frames rendered from
  NAIP 2010 (June 2010, another season); ground truth through the two GeoTIFFs' grids.

    .venv/bin/python scripts/make_demo_flight.py

The same through the command line::

    c3-matcher tiles build data/imagery/naip_timeseries/m_4709963_se_14_1_20200831.tif \\
        naip2020_z15.mbtiles --zoom 15 --format jpg
    c3-matcher dataset render data/imagery/naip_timeseries/m_4709963_se_14_1_20200831.tif \\
        naip2020_z15.mbtiles data/flights/naip_demo --frames 30
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from flight_kit import NAIP, NAIP_CREDIT, build_store, render

from c3_matcher_tools.dataset.flight_spec import FlightSpec
from c3_matcher_tools.dataset.progress import ProgressBar


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp) / "naip2020_z15.mbtiles"
        tiles = NAIP / "m_4709963_se_14_1_20200831.tif"
        report = build_store(tiles, store, 15, NAIP_CREDIT, progress=ProgressBar("tiles"))
        print(report, file=sys.stderr)
        for name, frames_tif in (
            ("naip_demo", "m_4709963_se_14_1_20200831.tif"),
            ("naip_cross_date", "m_4709963_se_14_1_20100629.tif"),
        ):
            spec = FlightSpec(NAIP / frames_tif, store, n_frames=30, absent_share=0.1, seed=1)
            render(spec, name, NAIP_CREDIT)
    return 0


if __name__ == "__main__":
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()  # no arguments: --help says what it writes, and writes nothing
    sys.exit(main())
