"""A store file rewritten in place while it is open (``truncate``, ``cp`` or ``cat >`` over it,
which empty the file before writing) never kills the process: a memory-mapped page past the
file's new end would be a SIGBUS, with no exception and no FDR record. A tile store emptied so
is an outage (``TileStoreUnusableError``) and, once the new bytes are written, serves the new
file's tiles; a map-features sidecar emptied so is unavailable (said once), not a crash. Each
case runs in a child process on a copy of a shipped store, so a signal fails the test instead
of killing pytest."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

from c3_matcher.tilestore.features import FeatureSet, MapFeatureStore, WindowFeatures, sidecar_path

FLIGHTS = Path(__file__).resolve().parents[2] / "data" / "flights"
STORE = FLIGHTS / "naip_demo" / "tiles.mbtiles"
OTHER = FLIGHTS / "gorinchem_z18" / "tiles.mbtiles"  # another store, smaller, other tiles

_TILES = textwrap.dedent("""
    import sys
    from pathlib import Path
    from c3_matcher.tilestore.mbtiles import MBTilesStore, TileStoreUnusableError
    path, other = Path(sys.argv[1]), sys.argv[2]
    with MBTilesStore(other) as source:
        new_zoom = source.zooms()[0]
        new_key = (new_zoom, *min(source.tiles(new_zoom)))
        new_tile = bytes(source.tile_bytes(*new_key))
    store = MBTilesStore(path, retry_s=0.0)
    zoom = store.zooms()[0]
    keys = [(zoom, *xy) for xy in store.tiles(zoom)]
    assert all(store.tile_bytes(*key) is not None for key in keys)
    with open(path, "r+b") as f:
        f.truncate(0)  # what `cp`, `cat >` and `truncate -s 0` do first
        for key in keys:
            try:
                store.tile_bytes(*key)
            except TileStoreUnusableError:
                continue
            raise AssertionError(f"tile {key} of an emptied store was served")
        print("emptied: unusable", flush=True)
        if sys.argv[3] == "overwrite":
            f.write(Path(other).read_bytes())
    if sys.argv[3] == "overwrite":
        assert bytes(store.tile_bytes(*new_key)) == new_tile
        assert all(store.tile_bytes(*key) is None for key in keys)
        print("overwritten: the new file's tiles", flush=True)
    store.close()
""")

_REWRITE = textwrap.dedent("""
    import sys
    from pathlib import Path
    from c3_matcher.errors import InvalidInputError
    from c3_matcher.tilestore.mbtiles import MBTilesStore
    path, other = Path(sys.argv[1]), sys.argv[2]
    with MBTilesStore(other) as source:
        new_zoom = source.zooms()[0]
        new_keys = [(new_zoom, *xy) for xy in source.tiles(new_zoom)]
        new_tiles = [bytes(source.tile_bytes(*key)) for key in new_keys]
    store = MBTilesStore(path)
    zoom = store.zooms()[0]
    assert store.tile_bytes(zoom, *min(store.tiles(zoom))) is not None
    Path(path).write_bytes(Path(other).read_bytes())  # between two reads: no outage seen
    failed = 0
    for _ in range(2):
        for key, tile in zip(new_keys, new_tiles):
            try:
                got = store.tile_bytes(*key)
            except InvalidInputError:
                failed += 1
                continue
            assert got is not None and bytes(got) == tile, key
    print("rewritten: failed reads", failed, flush=True)
    store.close()
""")

_SIDECAR = textwrap.dedent("""
    import sys
    from pathlib import Path
    from c3_matcher.tilestore.features import FeatureStoreUnavailableError, MapFeatureStore
    path, set_id = Path(sys.argv[1]), sys.argv[2]
    side = MapFeatureStore(path)
    fset = side.feature_set(set_id)
    assert fset is not None and side.window(fset, 15, 0, 0) is not None
    with open(path, "r+b") as f:
        f.truncate(0)
    try:
        got = side.window(fset, 15, 0, 0)
    except FeatureStoreUnavailableError as exc:
        print("emptied: unavailable", exc, flush=True)
    else:
        raise AssertionError(f"a window of an emptied sidecar was served: {got}")
    assert side.window(fset, 15, 0, 0) is None  # said once; within the outage, nothing
    side.close()
""")


def _run(script: str, *args: str) -> str:
    """``script`` run by a child Python with ``args``; its stdout. Fails naming the signal
    that killed it, or its stderr when it failed."""
    done = subprocess.run(
        [sys.executable, "-X", "faulthandler", "-c", script, *args],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    if done.returncode < 0:
        raise AssertionError(f"killed by {signal.Signals(-done.returncode).name}: {done.stderr}")
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_an_emptied_tile_store_is_an_outage_not_a_signal(tmp_path: Path) -> None:
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    assert _run(_TILES, str(path), str(OTHER), "truncate").splitlines() == ["emptied: unusable"]


def test_a_tile_store_overwritten_in_place_serves_the_new_files_tiles(tmp_path: Path) -> None:
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    assert _run(_TILES, str(path), str(OTHER), "overwrite").splitlines() == [
        "emptied: unusable",
        "overwritten: the new file's tiles",
    ]


def test_a_tile_store_rewritten_between_two_reads_serves_the_new_files_tiles(
    tmp_path: Path,
) -> None:
    """A connection that read the file before keeps its tables' old pages, which the new file
    holds other things in: the read that finds so fails, sees the file changed, and is read
    again on the new file, so no read fails."""
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(STORE, path)
    assert _run(_REWRITE, str(path), str(OTHER)).splitlines() == ["rewritten: failed reads 0"]


def test_an_emptied_sidecar_is_unavailable_not_a_signal(tmp_path: Path) -> None:
    path = sidecar_path(tmp_path / "tiles.mbtiles")
    fset = FeatureSet(
        "ab" * 32, "cd" * 32, "CPUExecutionProvider", 32, "clahe", 4, 448, 32, 64, "xfeat"
    )
    rng = np.random.default_rng(0)
    window = WindowFeatures(
        "ef" * 32,
        rng.uniform(4, 440, (500, 2)).astype(np.float32),
        np.sort(rng.uniform(0.1, 1.0, 500).astype(np.float32))[::-1].copy(),
        rng.normal(size=(500, 64)).astype(np.float32),
    )
    with MapFeatureStore(path, writable=True) as side:
        side.ensure_set(fset)
        side.put_windows(fset.set_id, [(15, gx, 0, window) for gx in range(8)])
        side.mark(fset.set_id, complete=True, windows=8)
    out = _run(_SIDECAR, str(path), fset.set_id)
    assert out.startswith("emptied: unavailable"), out
