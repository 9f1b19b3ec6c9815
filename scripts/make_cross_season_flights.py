"""Regenerate the cross-season flights in data/flights/ (committed; deterministic).

Every ordered pair of the three NAIP dates of data/imagery/naip_timeseries (2010-06, 2015-09,
2020-08): the tile store cut from one date (zoom 15, JPEG 90, as naip_demo's), the frames rendered
from another, ground truth through both GeoTIFF grids (the renderer maps each frame pixel to the
ground through the frames' GeoTIFF and to the tile through the store's mercator grid). 20 frames,
320x240, the demo flight's orbit and attitude spec otherwise. ``naip_cross_date`` (frames 2010,
store 2020, 30 frames) is the shipped pair already and is not re-rendered here.

Distractor-only flights (``absent_share = 1``: no frame has its true tile among its candidates,
only three distractors that do not overlap its footprint; every frame must raise
InsufficientInliersError, eval's false-confident bar is zero), one per shipped store, the frames
from another date (a flight has one store and one frames GeoTIFF):

- ``naip_distractors``: store 2020, frames 2015, 20 frames (the original; seed 16);
- ``naip_distractors_s2010``: store 2010, frames 2020, 12 frames (seed 17);
- ``naip_distractors_s2015``: store 2015, frames 2010, 12 frames (seed 18).

    .venv/bin/python scripts/make_cross_season_flights.py            # every flight above
    .venv/bin/python scripts/make_cross_season_flights.py NAME...    # only these (re-rendered)
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from flight_kit import NAIP, NAIP_CREDIT, build_store, render, unknown_flights

from c3_matcher_tools.dataset.flight_spec import FlightSpec

DATES = {
    "2010": "m_4709963_se_14_1_20100629.tif",
    "2015": "m_4709963_se_14_1_20150926.tif",
    "2020": "m_4709963_se_14_1_20200831.tif",
}
# (store date, frames date); 2020 <- 2010 ships as naip_cross_date
PAIRS = [("2020", "2015"), ("2015", "2010"), ("2015", "2020"), ("2010", "2015"), ("2010", "2020")]
# distractor-only flights beside naip_distractors (store 2020, frames 2015): (store, frames)
DISTRACTOR_PAIRS = [("2010", "2020"), ("2015", "2010")]


def main() -> int:
    only = set(sys.argv[1:])
    # (name, store date, frames date, absent share, frames); seeds 11, 12, ... in this order
    jobs = [(f"naip_s{s}_f{f}", s, f, 0.1, 20) for s, f in PAIRS]
    jobs.append(("naip_distractors", "2020", "2015", 1.0, 20))
    # appended after the shipped jobs so every earlier seed (and flight) stays as it is
    jobs += [(f"naip_distractors_s{s}", s, f, 1.0, 12) for s, f in DISTRACTOR_PAIRS]
    if unknown_flights(only, (job[0] for job in jobs)):
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        stores: dict[str, Path] = {}
        for date in ("2010", "2015", "2020"):
            stores[date] = Path(tmp) / f"naip{date}_z15.mbtiles"
            build_store(NAIP / DATES[date], stores[date], 15, NAIP_CREDIT)
        for seed, (name, store_date, frames_date, absent, n_frames) in enumerate(jobs, start=11):
            if only and name not in only:
                continue
            spec = FlightSpec(
                NAIP / DATES[frames_date],
                stores[store_date],
                n_frames=n_frames,
                absent_share=absent,
                seed=seed,
            )
            render(spec, name, NAIP_CREDIT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
