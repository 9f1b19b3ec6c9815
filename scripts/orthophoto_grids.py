"""Print what the ground tools read from every shipped orthophoto: its GSD through the orthophoto
loader (and where it came from), through the raster reader's rule (projected and as degrees), two
pixels' lon/lat through its grid, and the default tile-store zoom. Run it under two trees to show
that a change to the geodesy or the GeoTIFF reading moved nothing::

    .venv/bin/python scripts/orthophoto_grids.py > after.txt
"""

from __future__ import annotations

from pathlib import Path

from c3_matcher_tools.sim.orthophotos import load_orthophoto
from c3_matcher_tools.tilestore.geo import read_geotiff_grid, zoom_for_gsd
from c3_matcher_tools.tilestore.raster import grid_gsd_m

IMAGERY = Path(__file__).resolve().parents[1] / "data" / "imagery"


def main() -> None:
    for tif in sorted(IMAGERY.rglob("*.tif"), key=lambda p: p.name):
        photo = load_orthophoto(tif)
        grid = read_geotiff_grid(tif)
        corners = grid.px_to_lonlat([[0, 0], [10.5, 20.25]]).tolist()
        print(
            tif.name,
            repr(photo.gsd_m),
            photo.gsd_source,
            repr(grid_gsd_m(grid, geographic=False)),
            repr(grid_gsd_m(grid, geographic=True)),
            repr(corners),
            zoom_for_gsd(photo.gsd_m or 1.0, grid.centre_lonlat()[1]),
        )


if __name__ == "__main__":
    main()
