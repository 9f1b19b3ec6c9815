"""The built-in demo's tile ids (``data/demo/demo.json``) are where its tiles are: each id is the
lon/lat of its tile's centre pixel by the orthophoto's own georeference, read here with rasterio
and pyproj (the tools' ``geo`` extra), within a tenth of a tile px; and each tile is the crop of
the orthophoto its ``ortho_offset_px`` says (to a grey level on average: GDAL's JPEG decoder and
the one the demo was cut with differ by that; a crop one px off differs by 9)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyproj
import pytest
import rasterio

from c3_matcher.georef import haversine_m

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "data" / "demo"
META = json.loads((DEMO / "demo.json").read_text())


@pytest.mark.parametrize("tile", META["tiles"], ids=lambda t: t["file"])
def test_a_demo_tile_id_is_its_tiles_centre_by_the_orthophotos_georeference(
    tile: dict[str, Any],
) -> None:
    image = cv2.imread(str(DEMO / tile["file"]), cv2.IMREAD_COLOR)[:, :, ::-1]
    h, w = image.shape[:2]
    x0, y0 = (int(v) for v in tile["ortho_offset_px"])
    with rasterio.open(REPO / META["orthophoto"]) as ortho:
        rgb = ortho.read((1, 2, 3)).transpose(1, 2, 0)
        # the centre pixel ((w - 1) / 2, (h - 1) / 2); rasterio's transform maps pixel corners
        east, north = ortho.transform @ (x0 + (w - 1) / 2 + 0.5, y0 + (h - 1) / 2 + 0.5)
        to_wgs84 = pyproj.Transformer.from_crs(ortho.crs, "EPSG:4326", always_xy=True)
    crop = rgb[y0 : y0 + h, x0 : x0 + w].astype(np.int16)
    assert np.abs(image.astype(np.int16) - crop).mean() < 1.0
    lon, lat = to_wgs84.transform(east, north)
    _, id_lat, id_lon = tile["tile_id"]
    off_m = float(haversine_m([[lon, lat]], [[id_lon, id_lat]])[0])
    assert off_m / META["tile_gsd_m"] <= 0.1, f"{tile['file']}: its id is {off_m:.3f} m off"
