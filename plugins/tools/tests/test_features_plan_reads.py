"""``features build`` given its windows (``--flight-candidates``) reads only the tiles those
windows cover: it read and hashed every tile of the store however few windows it built (80
windows over an 820 MB store read most of it). The windows' digests, and so the sidecar's rows,
are those a digest of the whole store gives. XFeat in process, on two windows of the demo store
among thousands of tiles no window covers."""

from __future__ import annotations

import hashlib
import shutil
import sqlite3
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.tilestore.features import MapFeatureStore, sidecar_path
from c3_matcher_tools.features import build

FLIGHT = Path(__file__).resolve().parents[3] / "data" / "flights" / "naip_demo"
ZOOM, X, Y = 15, 7358, 11522  # an XYZ tile inside the demo store (7 x 5 tiles at zoom 15)
UNRELATED = [(ZOOM, x, row) for x in range(100, 160) for row in range(100, 150)]  # 3000 tiles


def _padded_store(where: Path) -> Path:
    """The demo store, with ``UNRELATED`` small tiles (and their digests) far from its own."""
    path = where / "tiles.mbtiles"
    shutil.copy(FLIGHT / "tiles.mbtiles", path)
    blobs = [(*k, f"tile {k}".encode()) for k in UNRELATED]
    with sqlite3.connect(path) as db:
        db.executemany("INSERT INTO tiles VALUES (?, ?, ?, ?)", blobs)
        db.executemany(
            "INSERT INTO c3_tile_digest VALUES (?, ?, ?, ?)",
            [(z, x, r, hashlib.sha256(b).hexdigest()) for z, x, r, b in blobs],
        )
    db.close()
    return path


class _Counted:
    """A tile source whose tile reads are noted in ``read``."""

    def __init__(self, source: Any, read: list[tuple[int, ...]]) -> None:
        self._source, self._read = source, read

    def tile_bytes(self, *key: int) -> Any:
        self._read.append(key)
        return self._source.tile_bytes(*key)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._source, name)

    def __enter__(self) -> _Counted:
        return self

    def __exit__(self, *exc: object) -> None:
        self._source.close()


@pytest.mark.slow
def test_a_build_of_given_windows_reads_only_the_tiles_they_cover(
    tmp_path: Path, engine_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from c3_matcher.config import load_settings

    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    store = _padded_store(tmp_path)
    windows = [(ZOOM, X, Y), (ZOOM, X + 1, Y)]
    read: list[tuple[int, ...]] = []
    opened = build.open_source
    monkeypatch.setattr(build, "open_source", lambda path: _Counted(opened(path), read))
    report = build.build_features(
        store, ["xfeat"], load_settings(None), window_px=256, stride_px=256, windows=windows,
        workers=0, progress=lambda line: None,
    )  # fmt: skip
    assert report.strategies["xfeat"]["extracted"] == 2
    assert sorted(read) == sorted(windows)  # 256 px windows on the tile grid: a tile each
    monkeypatch.setattr(build, "open_source", opened)
    whole = build.window_digests(windows, 256, 256, build.store_tile_digests(store))
    with MapFeatureStore(sidecar_path(store)) as sidecar:
        (fset,) = sidecar.feature_sets()
        done, damaged = sidecar.checked_windows(fset)
    assert not damaged
    assert done == whole
