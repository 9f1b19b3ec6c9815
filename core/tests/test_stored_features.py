"""The stored map features' read path over a real tile store: grid windows served as stored
(budget = prefix, off-grid candidates shifted into their own px), stale windows never served,
a row altered into finite garbage refused once, and a sidecar locked by another process costing
no wait (said once, tried again rarely). The features here are arrays written through the
store's own writer; the real engine's bit-for-bit agreement is in the tools' test_features.py."""

from __future__ import annotations

import hashlib
import re
import shutil
import sqlite3
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.testing.locks import exclusive_lock, release
from c3_matcher.tilestore.features import (
    FeatureRequest,
    FeatureSet,
    FeatureStoreUnavailableError,
    MapFeatureStore,
    StoredFeaturesCorruptError,
    WindowFeatures,
    covered_tiles,
    serve_window,
    sidecar_path,
    tile_digest,
    window_digest,
)
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher.tilestore.sidecar import PAGE_BYTES, SidecarDamagedError, set_aside

REPO = Path(__file__).resolve().parents[2]
STORE = REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
ZOOM, WINDOW, STRIDE = 15, 448, 32
REQUEST = FeatureRequest("ab" * 32, 32, 1024, 4096, 4, "clahe", "CPUExecutionProvider")


class Clock:
    """A settable monotonic clock (seconds)."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def _window(source: MBTilesStore, gx: int, gy: int, n: int = 50, seed: int = 0) -> WindowFeatures:
    keys = covered_tiles(ZOOM, (gx * STRIDE, gy * STRIDE), (WINDOW, WINDOW))
    digest = window_digest(keys, lambda k: _digest(source, k))
    rng = np.random.default_rng(seed)
    desc = rng.normal(size=(n, 64)).astype(np.float32)
    return WindowFeatures(
        digest,
        rng.uniform(4, WINDOW - 5, (n, 2)).astype(np.float32),
        np.sort(rng.uniform(0.1, 1.0, n).astype(np.float32))[::-1].copy(),
        desc / np.linalg.norm(desc, axis=1, keepdims=True),
    )


def _digest(source: MBTilesStore, key: tuple[int, int, int]) -> str | None:
    blob = source.tile_bytes(*key)
    return None if blob is None else tile_digest(blob)


@pytest.fixture
def store(tmp_path: Path) -> Iterator[tuple[MBTilesStore, tuple[int, int]]]:
    """A copy of the demo flight's store with one stored window (gx, gy) in its coverage."""
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    source = MBTilesStore(path)
    (x, y) = min(source.tiles(ZOOM))
    cell = (x * 256 // STRIDE + 2, y * 256 // STRIDE + 2)
    fset = FeatureSet(
        REQUEST.set_id(WINDOW), REQUEST.extractor_sha256, REQUEST.provider, 32, "clahe", 4,
        WINDOW, STRIDE, 64, "xfeat",
    )  # fmt: skip
    with MapFeatureStore(sidecar_path(path), writable=True) as side:
        side.ensure_set(fset)
        side.put_windows(fset.set_id, [(ZOOM, *cell, _window(source, *cell))])
        side.mark(fset.set_id, complete=True, windows=1)
    yield source, cell
    source.close()


def _serve(source: MBTilesStore, origin: tuple[int, int], request: FeatureRequest = REQUEST):
    return serve_window(source, request, ZOOM, origin, (WINDOW, WINDOW))  # type: ignore[arg-type]


def test_a_grid_window_is_served_as_stored_and_a_budget_is_its_prefix(store) -> None:
    source, (gx, gy) = store
    stored = _window(source, gx, gy)
    got = _serve(source, (gx * STRIDE, gy * STRIDE))
    assert got is not None and got.image_size == (WINDOW, WINDOW)
    assert np.array_equal(got.keypoints, stored.keypoints)
    assert np.array_equal(got.descriptors, stored.descriptors)
    assert np.array_equal(got.keypoint_scores, stored.scores)
    small = FeatureRequest(REQUEST.extractor_sha256, 32, 1024, 7, 4, "clahe")
    few = _serve(source, (gx * STRIDE, gy * STRIDE), small)
    assert few is not None and np.array_equal(few.descriptors, stored.descriptors[:7])


def test_an_off_grid_candidate_gets_the_nearest_window_in_its_own_px(store) -> None:
    source, (gx, gy) = store
    stored = _window(source, gx, gy)
    got = _serve(source, (gx * STRIDE + 10, gy * STRIDE - 16))  # nearest: (gx, gy)
    assert got is not None
    assert np.array_equal(got.keypoints, stored.keypoints + np.float32([-10, 16]))
    assert np.array_equal(got.descriptors, stored.descriptors)
    assert _serve(source, (gx * STRIDE + 17, gy * STRIDE)) is None  # nearest: gx + 1, not stored


def test_other_engines_devices_or_preprocessing_are_never_served(store) -> None:
    source, (gx, gy) = store
    origin = (gx * STRIDE, gy * STRIDE)
    fields = REQUEST.__dataclass_fields__
    assert list(fields)[:7] == [
        "extractor_sha256", "multiple", "max_long_side", "max_keypoints", "border_erode_px",
        "photometric", "provider",
    ]  # fmt: skip
    for other in (
        FeatureRequest("cd" * 32, 32, 1024, 4096, 4, "clahe", "CPUExecutionProvider"),
        FeatureRequest("ab" * 32, 32, 1024, 4096, 4, "clahe", "CUDAExecutionProvider"),
        FeatureRequest("ab" * 32, 32, 1024, 4096, 4, "none", "CPUExecutionProvider"),
        FeatureRequest("ab" * 32, 32, 1024, 4096, 2, "clahe", "CPUExecutionProvider"),
        FeatureRequest("ab" * 32, 64, 1024, 4096, 4, "clahe", "CPUExecutionProvider"),
        FeatureRequest("ab" * 32, 32, 256, 4096, 4, "clahe", "CPUExecutionProvider"),  # resized
    ):
        assert _serve(source, origin, other) is None, other
    assert _serve(source, origin) is not None


def test_a_window_whose_tiles_changed_is_not_served(store, tmp_path: Path) -> None:
    source, (gx, gy) = store
    key = covered_tiles(ZOOM, (gx * STRIDE, gy * STRIDE), (WINDOW, WINDOW))[0]
    source.close()
    where = "WHERE zoom_level=? AND tile_column=? AND tile_row=?"
    row = (key[0], key[1], (1 << key[0]) - 1 - key[2])
    with sqlite3.connect(tmp_path / "tiles.mbtiles") as db:  # one covered tile rebuilt
        (blob,) = db.execute(f"SELECT tile_data FROM tiles {where}", row).fetchone()
        blob = bytes(blob) + b"\x00"  # same pixels, other bytes
        db.execute(f"UPDATE tiles SET tile_data=? {where}", (blob, *row))
        if db.execute("SELECT 1 FROM sqlite_master WHERE name='c3_tile_digest'").fetchone():
            sha = hashlib.sha256(blob).hexdigest()
            db.execute(f"UPDATE c3_tile_digest SET sha256=? {where}", (sha, *row))
    changed = MBTilesStore(tmp_path / "tiles.mbtiles")
    try:
        assert _serve(changed, (gx * STRIDE, gy * STRIDE)) is None
    finally:
        changed.close()


def test_a_row_of_finite_garbage_is_refused_once_and_never_served(store, tmp_path: Path) -> None:
    source, (gx, gy) = store
    garbage = np.random.default_rng(1).uniform(-1, 1, (50, 64)).astype(np.float32)
    assert np.isfinite(garbage).all()
    with sqlite3.connect(sidecar_path(tmp_path / "tiles.mbtiles")) as db:
        db.execute("UPDATE window_features SET descriptors=?", (garbage.tobytes(),))
    with pytest.raises(StoredFeaturesCorruptError, match="checksum mismatch; refused"):
        _serve(source, (gx * STRIDE, gy * STRIDE))
    assert _serve(source, (gx * STRIDE, gy * STRIDE)) is None  # said once, never served
    with sqlite3.connect(sidecar_path(tmp_path / "tiles.mbtiles")) as db:  # wrong length too
        db.execute("UPDATE window_features SET scores=x'0000'")
    fresh = MapFeatureStore(sidecar_path(tmp_path / "tiles.mbtiles"))
    fset = fresh.feature_set(REQUEST.set_id(WINDOW))
    assert fset is not None
    with pytest.raises(StoredFeaturesCorruptError, match="undecodable"):
        fresh.window(fset, ZOOM, gx, gy)
    fresh.close()


def test_a_sidecar_locked_by_another_process_costs_no_wait(
    store, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source, (gx, gy) = store
    origin = (gx * STRIDE, gy * STRIDE)
    clock = Clock()
    side = MapFeatureStore(sidecar_path(tmp_path / "tiles.mbtiles"), retry_s=30.0, clock=clock)
    monkeypatch.setattr(source, "feature_store", lambda: side)  # the reader, on a set clock
    with exclusive_lock(sidecar_path(tmp_path / "tiles.mbtiles")) as holder:
        started = time.perf_counter()
        with pytest.raises(FeatureStoreUnavailableError, match="locked.*next try in 30 s"):
            _serve(source, origin)
        # no busy wait: SQLite's default would have waited 5 s here
        assert time.perf_counter() - started < 1.0
        for _ in range(20):  # said once; the store is not asked again before the retry time
            assert _serve(source, origin) is None
        clock.now += 31  # tried again, still locked: quiet, back off again
        assert _serve(source, origin) is None
        release(holder)
        assert _serve(source, origin) is None  # released, but not retried before its time
        clock.now += 31
        assert _serve(source, origin) is not None  # served again


def test_binary_descriptors_are_stored_and_served_in_their_own_dtype(store, tmp_path: Path):
    source, (gx, gy) = store
    request = FeatureRequest("ef" * 32, 32, 1024, 500, 4, "none", "CPUExecutionProvider")
    fset = FeatureSet(
        request.set_id(WINDOW), request.extractor_sha256, request.provider, 32, "none", 4,
        WINDOW, STRIDE, 32, "orb", descriptor_dtype="uint8",
    )  # fmt: skip
    floats = _window(source, gx, gy)
    packed = np.random.default_rng(2).integers(0, 256, (50, 32), dtype=np.uint8)
    stored = WindowFeatures(floats.window_digest, floats.keypoints, floats.scores, packed)
    with MapFeatureStore(sidecar_path(tmp_path / "tiles.mbtiles"), writable=True) as side:
        side.ensure_set(fset)
        side.put_windows(fset.set_id, [(ZOOM, gx, gy, stored)])
    got = _serve(source, (gx * STRIDE, gy * STRIDE), request)
    assert got is not None and got.descriptors.dtype == np.uint8
    assert np.array_equal(got.descriptors, packed)


def _not_a_database(path: Path) -> None:
    path.write_text("garbage\n")


def _pages_overwritten(path: Path) -> None:
    """A sidecar whose table pages (all but the first, the schema) are overwritten."""
    MapFeatureStore(path, writable=True).close()
    data = bytearray(path.read_bytes())
    for start in range(PAGE_BYTES, len(data), PAGE_BYTES):
        data[start : start + 100] = b"\xff" * 100
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("damage", [_not_a_database, _pages_overwritten])
def test_a_damaged_sidecar_is_refused_for_writing_and_left_as_it_is(
    tmp_path: Path, damage: Callable[[Path], None]
) -> None:
    path = sidecar_path(tmp_path / "tiles.mbtiles")
    damage(path)
    before = path.read_bytes()
    with pytest.raises(SidecarDamagedError, match=re.escape(str(path))):
        MapFeatureStore(path, writable=True)
    assert path.read_bytes() == before


def test_setting_a_sidecar_aside_renames_it_with_its_companions(tmp_path: Path) -> None:
    path = sidecar_path(tmp_path / "tiles.mbtiles")
    for suffix, text in (("", "garbage"), ("-wal", "old pages")):
        Path(f"{path}{suffix}").write_text(text)
    aside = set_aside(path)
    assert aside.name == f"{path.name}.damaged" and aside.read_text() == "garbage"
    assert Path(f"{aside}-wal").read_text() == "old pages"
    assert not path.exists() and not Path(f"{path}-wal").exists()
    path.write_text("garbage again")
    assert set_aside(path).name == f"{path.name}.damaged.1"  # the first one is kept
    with MapFeatureStore(path, writable=True) as fresh:  # a new sidecar in its place
        assert fresh.feature_sets() == []
