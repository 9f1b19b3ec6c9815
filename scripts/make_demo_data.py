"""Regenerate the built-in demo data in data/demo/ (committed; this documents how it was made).

One nav-camera frame rendered over a real orthophoto (Manila, OpenAerialMap, CC BY 4.0) with
yaw 120 deg and 18 deg of roll, lens distortion, a frame GSD half the tiles' and a photometric
shift; its true tile and two distractor tiles that do not overlap its footprint, shuffled. Each
tile id is the lon/lat of its tile's centre pixel ((w - 1) / 2, (h - 1) / 2) by the orthophoto's
own georeference (its GeoTIFF grid and CRS), at the web-mercator zoom nearest the tiles' GSD.

    .venv/bin/python scripts/make_demo_data.py [OUT_DIR]     # OUT_DIR: data/demo by default
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import cv2
import numpy as np

from c3_matcher.dto import TileId
from c3_matcher_tools.sim.render import OrthoTile
from c3_matcher_tools.sim.scenario import ScenarioSpec, build_scenario
from c3_matcher_tools.tilestore.geo import GeoGrid, read_geotiff_grid

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "data" / "demo"
ORDER = (2, 0, 1)  # the true tile is the 2nd candidate on the command line


def tile_id(grid: GeoGrid, tile: OrthoTile, zoom: int) -> TileId:
    """The id of ``tile`` (a crop of the orthophoto of ``grid``): its centre pixel's lon/lat by
    the orthophoto's georeference, at ``zoom``."""
    h, w = tile.image.shape[:2]
    centre = (tile.offset_px[0] + (w - 1) / 2, tile.offset_px[1] + (h - 1) / 2)
    lon, lat = grid.px_to_lonlat([centre])[0]
    return TileId(zoom, float(lat), float(lon))


def main(out: Path = OUT) -> None:
    ortho = REPO / "data/imagery/open_orthophotos/5b90f92da0d7280005fab355_4310.tif"
    grid = read_geotiff_grid(ortho)
    lon, lat = grid.centre_lonlat()
    spec = ScenarioSpec(
        ortho,
        yaw_deg=120,
        pitch_deg=0,
        roll_deg=18,
        frame_gsd_ratio=0.5,
        tile_size=512,
        image_size=(640, 480),
        focal_px=560,
        seed=7,
        reference_latlon=(lat, lon),
    )
    sc = build_scenario(spec)
    out.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out / "frame.jpg"), sc.frame.image[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 92])
    tiles = []
    for n, i in enumerate(ORDER):
        name = f"tile_{'abc'[n]}.png"
        cv2.imwrite(str(out / name), sc.tiles[i].image[:, :, ::-1])
        tiles.append(
            {
                "file": name,
                "tile_id": tile_id(grid, sc.tiles[i], sc.tile_ids[i].zoom).as_list(),
                "true": i == 0,
                "ortho_offset_px": list(sc.tiles[i].offset_px),
            }
        )
    cal = sc.calibration
    (out / "calibration.json").write_text(
        json.dumps(
            {
                "K": cal.K.tolist(),
                "distortion": cal.distortion.tolist(),
                "image_size": list(cal.image_size),
            },
            indent=2,
        )
        + "\n"
    )
    (out / "demo.json").write_text(
        json.dumps(
            {
                "orthophoto": str(spec.orthophoto.relative_to(REPO)),
                "attitude_deg": {
                    "roll": spec.roll_deg,
                    "pitch": spec.pitch_deg,
                    "yaw": spec.yaw_deg,
                },
                "height_m": round(sc.frame.height_m, 6),
                "tile_gsd_m": sc.tile_gsd_m,
                "tiles": tiles,
                "gt_homography_undistorted_frame_to_ortho": (
                    sc.frame.gt_homography_undistorted_to_ortho.tolist()
                ),
                "credit": "Imagery: (c) OpenAerialMap contributors, CC BY 4.0 (image "
                "5b90f92da0d7280005fab355, via OAM-TCD); see data/imagery/ATTRIBUTION.md",
            },
            indent=2,
        )
        + "\n"
    )
    print(
        f"wrote {out}: height {sc.frame.height_m:.2f} m, tile GSD {sc.tile_gsd_m:.4f} m, "
        f"tilt {math.degrees(math.acos(math.cos(math.radians(spec.roll_deg)))):.1f} deg, "
        f"true tile {tiles[ORDER.index(0)]['file']}; tile ids "
        f"{[t['tile_id'] for t in tiles]} {np.round(sc.frame.nadir_px, 1)}"
    )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("out_dir", nargs="?", type=Path, default=OUT, help=f"default {OUT}")
    main(parser.parse_args().out_dir)
