"""What the tile cache pays to key a store's candidate window, beside what the key used to cost.

    .venv/bin/python scripts/tile_cache_key_cost.py FLIGHT_DIR [WINDOW_PX ...]

For every candidate of every frame of the flight (its ``tiles.mbtiles``), on a fresh handle each
time as the flight gets one, at each window size (default: the dataset's ``candidate_size_px``
and 1024):

- ``content key``: the key the matcher computes (``tile_cache_key``: the window's stored tiles
  read and digested, nothing stitched or encoded);
- ``encoded key``: the former key, a digest of ``encoded()`` (the window stitched from its
  tiles, then encoded as a PNG);
- ``stitch``: ``decode()`` alone, the work a cache miss does anyway and a hit saves.

Printed: the median and p95 of each, in ms, on this machine's CPU.
"""

from __future__ import annotations

import functools
import hashlib
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from c3_matcher.dto import TileId, TilePixelsHandle
from c3_matcher.tile_cache import tile_cache_key
from c3_matcher.tilestore import MBTilesStore


def _timed_ms(
    ids: list[TileId], make: Callable[[TileId], TilePixelsHandle], step: str
) -> list[float]:
    times = []
    for tile_id in ids:
        handle = make(tile_id)
        started = time.perf_counter()
        if step == "content key":
            tile_cache_key(tile_id, handle)
        elif step == "encoded key":
            hashlib.blake2b(handle.encoded(), digest_size=16).hexdigest()
        else:
            handle.decode()
        times.append((time.perf_counter() - started) * 1e3)
    return times


def main(argv: list[str]) -> int:
    flight = Path(argv[0])
    spec = json.loads((flight / "dataset.json").read_text())
    sizes = [int(s) for s in argv[1:]] or [int(spec.get("candidate_size_px", 512)), 1024]
    ids = [
        TileId(*candidate["tile_id"])
        for line in (flight / "frames.jsonl").read_text().splitlines()
        for candidate in json.loads(line)["candidates"]
    ]
    with MBTilesStore(flight / "tiles.mbtiles") as store:
        timings = {
            (size, step): _timed_ms(ids, functools.partial(store.handle, size_px=size), step)
            for size in sizes
            for step in ("content key", "encoded key", "stitch")
        }
    for (size, step), ms in timings.items():
        p50, p95 = np.percentile(ms, [50, 95])
        where = f"{flight.name} {size:4d} px windows ({len(ids)})"
        print(f"{where}: {step:<11} p50 {p50:6.2f} ms  p95 {p95:6.2f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
