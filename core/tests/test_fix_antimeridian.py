"""A fix beside the antimeridian is a WGS84 longitude in [-180, 180).

The README's demo frame, matched against its true tile with the tile's id moved next to 180 deg
(the frame centre lies some 2.6 m west of the tile's centre): the centre is the one made at home,
moved, whichever side the window is named on; the footprint is the one made at home, moved, one
ring around the centre (continuous: where it crosses the line, its points beyond it lie beyond
180 deg, as GeoJSON readers draw a ring that is not cut)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from c3_matcher.dto import TileId
from c3_matcher.georef import lonlat_to_tile_px, tile_px_to_lonlat

from .demo_match import DEMO, run_match

TILE_GSD = "0.09682870211490897"
LAT, LON = 14.595529325314347, 120.98205740887816  # tile_b's centre (demo.json)


def _fix(tmp_path: Path, lon: float) -> dict[str, Any]:
    """The demo frame matched against tile_b centred at (LAT, ``lon``)."""
    argv = [
        *("match", "--query", str(DEMO / "frame.jpg"), "--tile", str(DEMO / "tile_b.png")),
        *("--tile-gsd", TILE_GSD, "--tile-id", f"21,{LAT!r},{lon!r}"),
        *("--calibration", str(DEMO / "calibration.json"), "--attitude", "18,0,120"),
        *("--height", "27.112037", "--strategy", "sift_magsac", "--no-correspondences"),
        *("--fdr", str(tmp_path / "fdr.jsonl")),
    ]
    proc = run_match(argv=argv)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return dict(json.loads(proc.stdout))


def _wrap(lon: float) -> float:
    return (lon + 180.0) % 360.0 - 180.0


@pytest.mark.parametrize("window_lon", [-180.0, -179.99999, 180.0, 179.99999])
def test_a_fix_beside_the_line_is_a_wgs84_longitude(tmp_path: Path, window_lon: float) -> None:
    home = _fix(tmp_path, LON)
    offset = home["centre_lon"] - LON
    assert offset < -2e-5  # west of the window's centre: across the line from a window at -180
    fix = _fix(tmp_path, window_lon)
    assert -180.0 <= fix["centre_lon"] < 180.0
    assert fix["centre_lon"] == pytest.approx(_wrap(window_lon + offset), abs=1e-9)
    assert fix["centre_lat"] == pytest.approx(home["centre_lat"], abs=1e-12)
    ring = np.asarray(fix["footprint"]) - [fix["centre_lon"], 0.0]
    ring_home = np.asarray(home["footprint"]) - [home["centre_lon"], 0.0]
    assert np.allclose(ring, ring_home, rtol=0, atol=1e-9)


def test_a_point_across_the_line_lies_beside_the_window() -> None:
    """A window centred 11 m west of 180 deg: a point 21 m across the line (-179.9998) lies in
    its east half, and its tile px give that point back."""
    tile = TileId(18, LAT, 179.9999)
    size = (512, 512)
    px = lonlat_to_tile_px(tile, size, [[-179.9998, LAT]])
    assert 256 < px[0, 0] < 512 and 255 < px[0, 1] < 257, px
    back = tile_px_to_lonlat(tile, size, px)
    assert np.allclose(back, [[-179.9998, LAT]], rtol=0, atol=1e-9)
