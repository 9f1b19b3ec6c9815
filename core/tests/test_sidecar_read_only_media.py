"""A map-feature sidecar (or an MBTiles store) in SQLite's WAL journal mode, as older versions
left their sidecars and other tools leave their stores, on read-only media: a reader of a WAL
file needs a ``-shm`` beside it, which cannot be made there, so SQLite's read-only open failed
("unable to open database file") and the flight extracted every candidate. Where nothing can
write the file (its file system mounted read-only, no companion beside it) it is now read as
immutable and served; where the ``-shm`` cannot be made otherwise the flight's warning says so
and names the command that makes it one file.

Read-only media in a test: the file system's read-only flag is the condition the reader checks
(``files.on_read_only_media``), set here for the test's folder; that SQLite cannot make a
``-shm`` there is real, for root too: the sidecar's name is as long as a name may be, so its
``-shm`` name is too long to be made."""

from __future__ import annotations

import dataclasses
import os
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.tilestore import files
from c3_matcher.tilestore.features import (
    FeatureRequest,
    FeatureSet,
    FeatureStoreUnavailableError,
    MapFeatureStore,
    WindowFeatures,
    covered_tiles,
    features_only,
    served_window,
    sidecar_path,
    stored_tile_digest,
    window_digest,
)
from c3_matcher.tilestore.mbtiles import MBTilesStore

REPO = Path(__file__).resolve().parents[2]
STORE = REPO / "data" / "flights" / "naip_demo" / "tiles.mbtiles"
ZOOM, WINDOW, STRIDE = 15, 448, 32
REQUEST = FeatureRequest("ab" * 32, 32, 1024, 4096, 4, "none", "CPUExecutionProvider")
FSET = FeatureSet(
    REQUEST.set_id(WINDOW), REQUEST.extractor_sha256, REQUEST.provider, 32, "none", 4,
    WINDOW, STRIDE, 64, "xfeat",
)  # fmt: skip

Cell = tuple[int, int]


def _window(source: MBTilesStore, cell: Cell) -> WindowFeatures:
    keys = covered_tiles(ZOOM, (cell[0] * STRIDE, cell[1] * STRIDE), (WINDOW, WINDOW))
    rng = np.random.default_rng(0)
    desc = rng.normal(size=(40, 64)).astype(np.float32)
    return WindowFeatures(
        window_digest(keys, lambda k: stored_tile_digest(source, k)),
        rng.uniform(4, WINDOW - 5, (40, 2)).astype(np.float32),
        np.sort(rng.uniform(0.1, 1.0, 40).astype(np.float32))[::-1].copy(),
        desc / np.linalg.norm(desc, axis=1, keepdims=True),
    )


def _leave_in_wal(path: Path) -> None:
    """Switch the SQLite file ``path`` to WAL journal mode and close it, as a build of an older
    version left its sidecar: one file, its header saying WAL, no companion beside it."""
    db = sqlite3.connect(path)
    assert db.execute("PRAGMA journal_mode=WAL").fetchone() == ("wal",)
    db.close()
    assert path.read_bytes()[18:20] == b"\x02\x02"
    assert sorted(p.name for p in path.parent.glob(f"{path.name}-*")) == []


def _media(folder: Path, longest: bool = False) -> tuple[Path, Cell, WindowFeatures]:
    """The demo store in ``folder`` with one stored window (its cell and features), its sidecar
    in WAL mode (made under a short name: its writer needs a ``-shm`` too), renamed when
    ``longest`` so that its sidecar's name is as long as a name may be there: no ``-shm`` can
    be made beside it."""
    folder.mkdir()
    most = os.pathconf(folder, "PC_NAME_MAX") - len(".features.sqlite")
    name = "m" * (most - len(".mbtiles")) + ".mbtiles" if longest else "tiles.mbtiles"
    path = folder / "tiles.mbtiles"
    shutil.copy(STORE, path)
    source = MBTilesStore(path)
    try:
        x, y = min(source.tiles(ZOOM))
        cell = (x * 256 // STRIDE + 2, y * 256 // STRIDE + 2)
        stored = _window(source, cell)
    finally:
        source.close()
    with MapFeatureStore(sidecar_path(path), writable=True) as side:
        side.ensure_set(FSET)
        side.put_windows(FSET.set_id, [(ZOOM, *cell, stored)])
        side.mark(FSET.set_id, complete=True, windows=1)
    _leave_in_wal(sidecar_path(path))
    sidecar_path(path).rename(sidecar_path(folder / name))
    path.rename(folder / name)
    return folder / name, cell, stored


def _read_only(monkeypatch: pytest.MonkeyPatch, folder: Path) -> None:
    """``folder``'s file system reads as mounted read-only."""
    real = files.on_read_only_media
    inside = folder.resolve()
    monkeypatch.setattr(
        files, "on_read_only_media", lambda p: inside in Path(p).parents or real(Path(p))
    )


def _serve(source: MBTilesStore, cell: Cell) -> object:
    origin = (cell[0] * STRIDE, cell[1] * STRIDE)
    return features_only(served_window(source, REQUEST, ZOOM, origin, (WINDOW, WINDOW)))  # type: ignore[arg-type]


def test_a_wal_sidecar_on_read_only_media_is_served_and_nothing_is_made_beside_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path, cell, stored = _media(tmp_path / "media", longest=True)
    _read_only(monkeypatch, path.parent)
    before = sorted(p.name for p in path.parent.iterdir())
    source = MBTilesStore(path)
    try:
        got = _serve(source, cell)
    finally:
        source.close()
    assert got is not None, "the stored window was not served"
    assert np.array_equal(got.descriptors, stored.descriptors)  # type: ignore[attr-defined]
    assert np.array_equal(got.keypoints, stored.keypoints)  # type: ignore[attr-defined]
    assert sorted(p.name for p in path.parent.iterdir()) == before


def test_a_wal_store_on_read_only_media_is_read_and_nothing_is_made_beside_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "media").mkdir()
    path = tmp_path / "media" / "tiles.mbtiles"  # another tool's store, left in WAL mode
    shutil.copy(STORE, path)
    _leave_in_wal(path)
    _read_only(monkeypatch, path.parent)
    source = MBTilesStore(path)
    try:
        key = min(source.tiles(ZOOM))
        blob = source.tile_bytes(ZOOM, *key)
    finally:
        source.close()
    original = MBTilesStore(STORE)
    try:
        assert blob is not None and bytes(blob) == bytes(original.tile_bytes(ZOOM, *key) or b"")
    finally:
        original.close()
    assert sorted(p.name for p in path.parent.iterdir()) == ["tiles.mbtiles"]


def test_a_wal_sidecar_whose_shm_cannot_be_made_says_why_and_what_makes_it_one_file(
    tmp_path: Path,
) -> None:
    path, cell, _ = _media(
        tmp_path / "media", longest=True
    )  # not read-only media: a writer may come
    side = sidecar_path(path)
    source = MBTilesStore(path)
    try:
        with pytest.raises(FeatureStoreUnavailableError) as said:
            _serve(source, cell)
        assert _serve(source, cell) is None  # said once; the flight extracts
    finally:
        source.close()
    text = str(said.value)
    assert text.startswith(f"{side}: cannot be read here: "), text
    assert f"WAL journal mode, which needs a {side.name}-shm file beside it" in text, text
    assert "`c3-matcher features build` of its store, where it can be written" in text, text
    assert text.endswith("; extracting instead, next try in 30 s"), text
    assert "unable to open database file" not in text


def test_a_sidecar_a_build_is_writing_is_read_with_its_writer_on_read_only_looking_media(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Never immutable while a writer may be there: its -wal and -shm lie beside the file, and
    the reader sees what the writer committed (an immutable read would miss the -wal's pages)."""
    path, cell, stored = _media(tmp_path / "media")
    _read_only(monkeypatch, path.parent)
    other = dataclasses.replace(FSET, set_id=f"{FSET.set_id}:another")
    with MapFeatureStore(sidecar_path(path), writable=True) as writer:
        writer.ensure_set(other)
        writer.put_windows(other.set_id, [(ZOOM, *cell, stored)])
        reader = MapFeatureStore(sidecar_path(path))
        try:
            assert reader.feature_set(other.set_id) is not None
            got = reader.window(other, ZOOM, *cell)
            assert got is not None and np.array_equal(got.descriptors, stored.descriptors)
        finally:
            reader.close()
