"""The features sidecar as a file: a build that ends while a reader holds the sidecar open
still leaves it one self-contained file (checkpointed, out of WAL, once the reader lets go), or
says it could not, naming the file and who holds it; a sidecar of an older schema (no
``descriptor_dtype``) is refused for writing as damage (set aside and built anew by ``features
build``), never migrated, and left as it is."""

from __future__ import annotations

import re
import shutil
import sqlite3
import threading
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.tilestore.features import FeatureSet, MapFeatureStore, WindowFeatures
from c3_matcher.tilestore.sidecar import SidecarDamagedError
from c3_matcher.tilestore.sidecar_file import SidecarInUseError

WINDOW = 448


def _set(name: str) -> FeatureSet:
    sha = name * 64
    return FeatureSet(
        f"{sha}:CPU:hw32:none:e4:w{WINDOW}", sha, "CPU", 32, "none", 4, WINDOW, 32, 64, name
    )


def _window(seed: int) -> WindowFeatures:
    rng = np.random.default_rng(seed)
    return WindowFeatures(
        f"{seed:064x}",
        rng.uniform(0, WINDOW, (20, 2)).astype(np.float32),
        np.linspace(1.0, 0.1, 20, dtype=np.float32),
        rng.normal(size=(20, 64)).astype(np.float32),
    )


def _build(writer: MapFeatureStore, fset: FeatureSet) -> None:
    writer.ensure_set(fset)
    writer.put_windows(fset.set_id, [(15, 1, 2, _window(1))])
    writer.mark(fset.set_id, complete=True, windows=1)


def _sidecar_with_one_set(tmp_path: Path) -> Path:
    path = tmp_path / "tiles.mbtiles.features.sqlite"
    with MapFeatureStore(path, writable=True) as writer:
        _build(writer, _set("a"))
    return path


def _alone(path: Path, where: Path) -> Path:
    """``path`` copied without its ``-wal`` and ``-shm``, as onto read-only media."""
    where.mkdir()
    return Path(shutil.copy(path, where / path.name))


def test_a_build_ending_while_a_reader_holds_the_sidecar_leaves_one_file(tmp_path: Path):
    """The reader lets go while the writer closes: the writer waits for it, and the file alone
    (no -wal) holds the new set, in rollback-journal mode (WAL needs a -shm to be read)."""
    path = _sidecar_with_one_set(tmp_path)
    opened, written, reread = threading.Event(), threading.Event(), threading.Event()

    def reader() -> None:  # as the flight holds it: kept open, read now and then
        fs = MapFeatureStore(path)
        assert len(fs.feature_sets()) == 1
        opened.set()
        written.wait(10)
        assert len(fs.feature_sets()) == 2  # read through the writer's WAL
        reread.set()
        threading.Event().wait(0.3)  # still open when the writer starts closing
        fs.close()

    thread = threading.Thread(target=reader)
    thread.start()
    assert opened.wait(10)
    writer = MapFeatureStore(path, writable=True, leave_wal_s=10)
    _build(writer, _set("b"))
    written.set()
    assert reread.wait(10)
    writer.close()
    thread.join()
    copy = _alone(path, tmp_path / "media")
    assert copy.read_bytes()[18:20] == b"\x01\x01"
    reader = MapFeatureStore(copy)
    try:
        assert sorted(s.strategy for s in reader.feature_sets()) == ["a", "b"]
    finally:
        reader.close()


def test_a_reader_that_never_lets_go_is_named_not_silently_left_in_wal(tmp_path: Path):
    path = _sidecar_with_one_set(tmp_path)
    held = MapFeatureStore(path)
    try:
        assert len(held.feature_sets()) == 1
        writer = MapFeatureStore(path, writable=True, leave_wal_s=0.3)
        _build(writer, _set("b"))
        assert len(held.feature_sets()) == 2  # read through the writer's WAL
        with pytest.raises(SidecarInUseError) as caught:
            writer.close()
        why = str(caught.value)
        assert why.startswith(f"{path}: not left one self-contained file")
        assert "still in WAL mode" in why and re.search(r"held open by this process \(pid", why)
        assert isinstance(caught.value, sqlite3.OperationalError)  # the build: "cannot be written"
        copy = _alone(path, tmp_path / "copy")  # checkpointed all the same: its sets in the file
        with sqlite3.connect(copy) as db:
            assert db.execute("SELECT COUNT(*) FROM window_sets").fetchone() == (2,)
    finally:
        held.close()
    with MapFeatureStore(path, writable=True):  # run again once the reader is gone: one file
        pass
    assert path.read_bytes()[18:20] == b"\x01\x01"


def test_a_reader_in_a_transaction_leaves_the_new_set_only_in_the_wal_and_says_so(tmp_path):
    path = _sidecar_with_one_set(tmp_path)
    held = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        writer = MapFeatureStore(path, writable=True, leave_wal_s=0.3)
        held.execute("BEGIN")
        assert held.execute("SELECT COUNT(*) FROM window_sets").fetchone() == (1,)
        _build(writer, _set("b"))
        with pytest.raises(SidecarInUseError, match=re.escape(f"only in {path.name}-wal")):
            writer.close()
    finally:
        held.close()


def test_an_error_in_flight_is_not_hidden_by_a_reader_holding_the_sidecar(tmp_path: Path):
    path = _sidecar_with_one_set(tmp_path)
    held = MapFeatureStore(path)
    try:
        with (
            pytest.raises(KeyError, match="the build's own"),
            MapFeatureStore(path, writable=True, leave_wal_s=30) as writer,
        ):
            _build(writer, _set("b"))
            assert len(held.feature_sets()) == 2
            raise KeyError("the build's own")
    finally:
        held.close()


OLD_SCHEMA = """
CREATE TABLE window_sets (
    set_id TEXT PRIMARY KEY, extractor_sha256 TEXT NOT NULL, provider TEXT NOT NULL,
    multiple INTEGER NOT NULL, photometric TEXT NOT NULL, border_erode_px INTEGER NOT NULL,
    window_px INTEGER NOT NULL, stride_px INTEGER NOT NULL, descriptor_dim INTEGER NOT NULL,
    strategy TEXT NOT NULL, complete INTEGER NOT NULL DEFAULT 0,
    windows INTEGER NOT NULL DEFAULT 0, created TEXT NOT NULL);
CREATE TABLE window_features (
    set_id TEXT NOT NULL, zoom INTEGER NOT NULL, gx INTEGER NOT NULL, gy INTEGER NOT NULL,
    window_digest TEXT NOT NULL, n INTEGER NOT NULL, keypoints BLOB NOT NULL,
    scores BLOB NOT NULL, descriptors BLOB NOT NULL, checksum TEXT NOT NULL,
    PRIMARY KEY (set_id, zoom, gx, gy)) WITHOUT ROWID;
"""  # before 2026-11-23: no descriptor_dtype (every descriptor stored cast to float32)


def test_a_sidecar_of_the_older_schema_is_refused_as_damage_and_left_as_it_is(tmp_path: Path):
    """It was an OperationalError ("no such column: descriptor_dtype"), which ``features build``
    neither sets aside nor builds past; as damage it is set aside and built anew. Never migrated:
    an old binary-descriptor set (cast to float32) would be served as float32 under its id."""
    path = tmp_path / "tiles.mbtiles.features.sqlite"
    with sqlite3.connect(path) as db:
        db.executescript(OLD_SCHEMA)
        db.execute(
            "INSERT INTO window_sets VALUES (?, ?, 'CPU', 32, 'none', 4, 448, 32, 32, 'orb', 1, "
            "0, '2026-11-01T00:00:00Z')",
            ("ef" * 32 + ":CPU:hw32:none:e4:w448", "ef" * 32),
        )
    before = path.read_bytes()
    expected = re.escape(
        f"{path}: schema of another version (window_sets: no column descriptor_dtype); its "
        "features cannot be kept"
    )
    with pytest.raises(SidecarDamagedError, match=expected):
        MapFeatureStore(path, writable=True)
    assert path.read_bytes() == before
    assert not Path(f"{path}-wal").exists()
