"""The stored map features' read path over a real tile store: grid windows served as stored
(budget = prefix, off-grid candidates shifted into their own px), stale windows never served,
a row altered into finite garbage refused once, and a sidecar locked by another process costing
no wait (said once, tried again rarely). Damage: a window whose pages SQLite finds malformed is
refused once naming it while the other windows are still served; the writer sorts intact rows
from damaged ones and reports damaged pages as a damaged sidecar; a closed sidecar is one file
(no WAL) read without write access. The features here are arrays written through the
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
    features_only,
    served_window,
    sidecar_path,
    tile_digest,
    window_digest,
)
from c3_matcher.tilestore.files import set_aside
from c3_matcher.tilestore.mbtiles import MBTilesStore
from c3_matcher.tilestore.sidecar import PAGE_BYTES, SidecarDamagedError

REPO = Path(__file__).resolve().parents[2]
STORE = REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
ZOOM, WINDOW, STRIDE = 15, 448, 32
REQUEST = FeatureRequest("ab" * 32, 32, 1024, 4096, 4, "clahe", "CPUExecutionProvider")
FSET = FeatureSet(
    REQUEST.set_id(WINDOW), REQUEST.extractor_sha256, REQUEST.provider, 32, "clahe", 4,
    WINDOW, STRIDE, 64, "xfeat",
)  # fmt: skip


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
    with MapFeatureStore(sidecar_path(path), writable=True) as side:
        side.ensure_set(FSET)
        side.put_windows(FSET.set_id, [(ZOOM, *cell, _window(source, *cell))])
        side.mark(FSET.set_id, complete=True, windows=1)
    yield source, cell
    source.close()


def _serve(source: MBTilesStore, origin: tuple[int, int], request: FeatureRequest = REQUEST):
    return features_only(served_window(source, request, ZOOM, origin, (WINDOW, WINDOW)))  # type: ignore[arg-type]


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
    moved = stored.keypoints + np.float32([-10, 16])
    on = ((moved >= -0.5) & (moved <= WINDOW - 0.5)).all(axis=1)
    assert not on.all()  # the shift takes some keypoints off the candidate's window: left out
    assert np.array_equal(got.keypoints, moved[on])
    assert np.array_equal(got.descriptors, stored.descriptors[on])
    assert np.array_equal(got.keypoint_scores, stored.scores[on])
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
        FeatureRequest("ab" * 32, 32, 1024, 4096, 4, "clahe", "CPUExecutionProvider", 2),  # x2
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


N = 4096  # keypoints of a window below
Cell = tuple[int, int]


@pytest.fixture
def three_rows(tmp_path: Path) -> Iterator[tuple[MBTilesStore, list[Cell]]]:
    """A copy of the demo flight's store with three stored windows of ``N`` keypoints (rows of
    about 1 MB: chains of overflow pages) in its coverage, written in key order in one
    transaction (the last one's overflow pages end the file)."""
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    source = MBTilesStore(path)
    (x, y) = min(source.tiles(ZOOM))
    cells = [(x * 256 // STRIDE + 2 + i, y * 256 // STRIDE + 2) for i in range(3)]
    with MapFeatureStore(sidecar_path(path), writable=True) as side:
        side.ensure_set(FSET)
        side.put_windows(
            FSET.set_id, [(ZOOM, *c, _window(source, *c, N, seed)) for seed, c in enumerate(cells)]
        )
        side.mark(FSET.set_id, complete=True, windows=len(cells))
    yield source, cells
    source.close()


def _origin(cell: Cell) -> tuple[int, int]:
    return cell[0] * STRIDE, cell[1] * STRIDE


def _break_last_chain(path: Path) -> None:
    """Point an overflow page of the last row's chain past the end of the file: SQLite reads
    that row as malformed, and the others as they are."""
    data = bytearray(path.read_bytes())
    start = (len(data) // PAGE_BYTES - 3) * PAGE_BYTES
    data[start : start + 4] = b"\xff" * 4  # the next page's number
    path.write_bytes(bytes(data))


def test_a_window_on_damaged_pages_is_refused_naming_it_and_the_others_are_served(three_rows):
    source, cells = three_rows
    side = sidecar_path(source.path)
    _break_last_chain(side)
    db = sqlite3.connect(f"file:{side}?mode=ro", uri=True)  # the damage is SQLite's
    try:
        with pytest.raises(sqlite3.DatabaseError, match="malformed"):
            db.execute(
                "SELECT descriptors FROM window_features WHERE set_id=? AND zoom=? AND gx=? "
                "AND gy=?",
                (FSET.set_id, ZOOM, *cells[2]),
            ).fetchone()
    finally:
        db.close()
    gx, gy = cells[2]
    where = re.escape(f"{side}: window {ZOOM}/{gx}/{gy} of set {FSET.set_id[:12]}...")
    with pytest.raises(StoredFeaturesCorruptError, match=f"{where}: unreadable .*malformed"):
        _serve(source, _origin(cells[2]))
    assert _serve(source, _origin(cells[2])) is None  # said once, never served
    for seed, cell in enumerate(cells[:2]):  # not an outage of the whole store
        got = _serve(source, _origin(cell))
        assert got is not None
        assert np.array_equal(got.descriptors, _window(source, *cell, N, seed).descriptors)


def test_the_writer_sorts_intact_rows_from_damaged_ones(three_rows) -> None:
    source, cells = three_rows
    side = sidecar_path(source.path)
    with sqlite3.connect(side) as db:
        db.execute("UPDATE window_features SET n=n+1 WHERE gx=?", (cells[0][0],))
        db.execute(
            "UPDATE window_features SET descriptors=substr(descriptors, 1, 1000) WHERE gx=?",
            (cells[1][0],),
        )
    with MapFeatureStore(side, writable=True) as writer:
        intact, damaged = writer.checked_windows(FSET)
    assert set(intact) == {(ZOOM, *cells[2])}
    assert intact[(ZOOM, *cells[2])] == _window(source, *cells[2], N, 2).window_digest
    assert set(damaged) == {(ZOOM, *cells[0]), (ZOOM, *cells[1])}
    assert all(why.startswith("undecodable") for why in damaged.values()), damaged


def test_the_writer_reports_damaged_pages_as_a_damaged_sidecar(three_rows) -> None:
    source, _ = three_rows
    side = sidecar_path(source.path)
    _break_last_chain(side)
    with MapFeatureStore(side, writable=True) as writer:  # the header and the sets are fine
        assert writer.feature_set(FSET.set_id) is not None
        with pytest.raises(SidecarDamagedError, match=re.escape(f"{side}: ") + ".*malformed"):
            writer.checked_windows(FSET)


def test_a_closed_sidecar_is_one_file_read_without_write_access(three_rows) -> None:
    source, cells = three_rows
    side = sidecar_path(source.path)
    header = side.read_bytes()[:100]
    assert header[18:20] == b"\x01\x01"  # rollback journal: WAL would need a -shm to read it
    assert not Path(f"{side}-wal").exists() and not Path(f"{side}-shm").exists()
    with MapFeatureStore(side, writable=True) as writer:  # a resumed build: WAL while open
        assert writer.feature_set(FSET.set_id) is not None
        assert side.read_bytes()[18:20] == b"\x02\x02"
    assert side.read_bytes()[18:20] == b"\x01\x01"
    reader = MapFeatureStore(side)
    try:
        assert reader.window(FSET, ZOOM, *cells[0]) is not None
    finally:
        reader.close()
