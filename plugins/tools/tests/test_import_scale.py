"""What ``dataset import`` costs grows with the flight, not with the tile store.

Candidates are found from the store's tile index in one query a frame, and only the tiles
proposed are read (their sha256 checked): the answer is the one a lookup of every tile of the
search square gives, on the shipped store and on one with holes. The dataset's store is a hard
link to the user's where both are on one filesystem (a copy where a link is refused), and it
keeps its tiles when the user rebuilds or deletes their store."""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import shutil
import sqlite3
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.dto import TileId
from c3_matcher.serialize import load_calibration
from c3_matcher.tilestore.base import tile_centre_id
from c3_matcher.tilestore.geo import TILE_PX, lonlat_to_world_px
from c3_matcher.tilestore.mbtiles import MBTilesStore, TileDigestError
from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.dataset.importer import ImportSpec, import_csv_flight
from c3_matcher_tools.dataset.proposals import propose_from_store
from c3_matcher_tools.dataset.sources.options import ProposalOptions
from c3_matcher_tools.dataset.telemetry import TelemetryRow
from c3_matcher_tools.tilestore.writer import MBTilesWriter

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
STORE = DEMO / "tiles.mbtiles"
CALIBRATION = load_calibration(DEMO / "calibration.json")
ZOOM = 15
# the shipped store's tiles: columns 7355..7361, XYZ rows 11520..11524 at zoom 15
COLUMNS, ROWS = range(7355, 7362), range(11520, 11525)


def _per_tile(
    store: MBTilesStore, lonlat: tuple[float, float], options: ProposalOptions
) -> list[tuple[TileId, float]] | None:
    """The candidates of a look point found by reading every tile of the search square (the
    answer the one-query search must give): the tile under the point, then the others nearest
    first, those within the uncertainty before the rest."""
    p = lonlat_to_world_px([lonlat], ZOOM)[0]
    m_per_px = TileId(ZOOM, lonlat[1], lonlat[0]).web_mercator_gsd_m()
    tx, ty = int(p[0] // TILE_PX), int(p[1] // TILE_PX)
    if store.tile_bytes(ZOOM, tx, ty) is None:
        return None
    ring = max(2, math.ceil(options.uncertainty_m / (m_per_px * TILE_PX)) + 1)
    ring = max(ring, math.ceil(math.sqrt(options.candidates)) + 1)
    near = []
    for x in range(tx - ring, tx + ring + 1):
        for y in range(ty - ring, ty + ring + 1):
            if (x, y) == (tx, ty) or store.tile_bytes(ZOOM, x, y) is None:
                continue
            dx = max(x * TILE_PX - p[0], 0.0, p[0] - (x + 1) * TILE_PX)
            dy = max(y * TILE_PX - p[1], 0.0, p[1] - (y + 1) * TILE_PX)
            edge_m = math.hypot(dx, dy) * m_per_px
            centre = math.hypot((x + 0.5) * TILE_PX - p[0], (y + 0.5) * TILE_PX - p[1])
            near.append((0.0 if edge_m <= options.uncertainty_m else 1.0, centre, x, y, edge_m))
    near.sort()
    picked = [(tile_centre_id(ZOOM, tx, ty), 0.0)]
    return (
        picked + [(tile_centre_id(ZOOM, x, y), m) for *_, x, y, m in near][: options.candidates - 1]
    )


def _rows() -> list[TelemetryRow]:
    """Level vehicles (looking straight down) on a grid over the store and beyond its edges."""
    lons = [-99.1875 + 0.0047 * i for i in range(15)]
    lats = [47.0010 + 0.0041 * j for j in range(10)]
    points = [(lat, lon) for lat in lats for lon in lons]
    return [
        TelemetryRow(i, float(i), "x.jpg", la, lo, 300.0, 0.0, 0.0, 0.0)
        for i, (la, lo) in enumerate(points)
    ]


def _with_holes(tmp_path: Path) -> Path:
    """The shipped store without a third of its tiles, and one tile left as an empty row (no
    data, no sha256: what another tool may write for a tile it has not)."""
    store = tmp_path / "holes.mbtiles"
    shutil.copyfile(STORE, store)
    db = sqlite3.connect(store)
    with db:
        for table in ("tiles", "c3_tile_digest"):
            db.execute(f"DELETE FROM {table} WHERE (tile_column + 2 * tile_row) % 3 = 0")
        db.execute(
            "UPDATE tiles SET tile_data = NULL WHERE tile_column = 7358 AND tile_row = 21245"
        )
        db.execute("DELETE FROM c3_tile_digest WHERE tile_column = 7358 AND tile_row = 21245")
    db.close()
    return store


@pytest.mark.parametrize("holes", [False, True])
@pytest.mark.parametrize(
    ("uncertainty_m", "candidates"), [(0.0, 1), (30.0, 3), (400.0, 4), (2500.0, 9), (9000.0, 20)]
)
def test_candidates_are_those_a_lookup_of_every_tile_gives(
    tmp_path: Path, holes: bool, uncertainty_m: float, candidates: int
) -> None:
    path = _with_holes(tmp_path) if holes else STORE
    options = ProposalOptions(path, uncertainty_m=uncertainty_m, candidates=candidates)
    rows = _rows()
    proposed = propose_from_store(rows, CALIBRATION, options)
    with MBTilesStore(path) as store:
        expected = [_per_tile(store, (r.lon, r.lat), options) for r in rows]
    assert [cands for _, cands in proposed.looks] == expected
    found = [cands for cands in expected if cands is not None]
    assert len(found) > 20 and any(len(c) == candidates for c in found)  # the test sees some
    assert [r.line for r in proposed.outside] == [
        r.line for r, e in zip(rows, expected) if e is None
    ]


def test_a_frame_reads_only_the_tiles_it_proposes(monkeypatch: pytest.MonkeyPatch) -> None:
    """At the widest search the square holds 65 x 65 tiles; a frame reads (and checks the
    sha256 of) the tile under its look point and its other candidates, no more."""
    reads: list[tuple[int, int, int]] = []
    read = MBTilesStore.tile_bytes

    def counted(self: MBTilesStore, zoom: int, x: int, y: int) -> memoryview | None:
        reads.append((zoom, x, y))
        return read(self, zoom, x, y)

    monkeypatch.setattr(MBTilesStore, "tile_bytes", counted)
    rows = _rows()
    options = ProposalOptions(STORE, uncertainty_m=9000.0, candidates=3)
    proposed = propose_from_store(rows, CALIBRATION, options)
    inside = sum(1 for _, cands in proposed.looks if cands is not None)
    assert len(reads) <= len(rows) + inside * (options.candidates - 1), len(reads)


def _damaged(tmp_path: Path, name: str, column: int, xyz_row: int) -> Path:
    """The shipped store with the bytes of tile (column, row) changed (its sha256 kept)."""
    store = tmp_path / name
    shutil.copyfile(STORE, store)
    db = sqlite3.connect(store)
    with db:
        db.execute(
            "UPDATE tiles SET tile_data = substr(tile_data, 1, 500) WHERE tile_column = ? AND "
            "tile_row = ?",
            (column, (1 << ZOOM) - 1 - xyz_row),
        )
    db.close()
    return store


def test_a_damaged_tile_is_never_proposed(tmp_path: Path) -> None:
    """A damaged tile the search would propose is refused, named; one it does not propose
    leaves the candidates as they are."""
    row = TelemetryRow(2, 0.0, "x.jpg", 47.0203620, -99.1548225, 300.0, 0.0, 0.0, 0.0)
    options = ProposalOptions(STORE, uncertainty_m=400.0, candidates=3)
    ((_, intact),) = propose_from_store([row], CALIBRATION, options).looks
    assert intact is not None
    p = lonlat_to_world_px([[intact[1][0].lon, intact[1][0].lat]], ZOOM)[0]
    second = (int(p[0] // TILE_PX), int(p[1] // TILE_PX))
    chosen = _damaged(tmp_path, "chosen.mbtiles", *second)
    with pytest.raises(TileDigestError, match=f"tile {ZOOM}/{second[0]}/{second[1]}: sha256"):
        propose_from_store([row], CALIBRATION, ProposalOptions(chosen, 400.0, 3))
    far = _damaged(tmp_path, "far.mbtiles", COLUMNS[0], ROWS[0])  # not proposed
    ((_, cands),) = propose_from_store([row], CALIBRATION, ProposalOptions(far, 400.0, 3)).looks
    assert cands == intact


def _flight(root: Path, store: Path, frames: int = 4) -> ImportSpec:
    """The first ``frames`` demo frames as a user has them (images, telemetry CSV) against
    ``store``, 300 m of uncertainty, 3 candidates."""
    images = root / "images"
    images.mkdir(parents=True)
    lines = ["time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg"]
    for line in (DEMO / "frames.jsonl").read_text().splitlines()[:frames]:
        f = json.loads(line)
        name = Path(f["image"]).name
        shutil.copyfile(DEMO / f["image"], images / name)
        p, (r, pi, y) = f["pose"], f["attitude_deg"]
        t = f["captured_at_ns"] / 1e9
        lines.append(f"{t},{name},{p['nadir_lat']},{p['nadir_lon']},{f['height_m']},{r},{pi},{y}")
    (root / "telemetry.csv").write_text("\n".join(lines) + "\n")
    proposal = ProposalOptions(store, uncertainty_m=300.0, candidates=3)
    return ImportSpec(images, root / "telemetry.csv", DEMO / "calibration.json", proposal)


def _users_store(tmp_path: Path) -> Path:
    store = tmp_path / "maps" / "area.mbtiles"
    store.parent.mkdir()
    shutil.copyfile(STORE, store)
    return store


def test_the_datasets_store_is_a_hard_link_to_the_users_store(tmp_path: Path) -> None:
    store = _users_store(tmp_path)
    report = import_csv_flight(_flight(tmp_path, store), tmp_path / "flight")
    linked = tmp_path / "flight" / "tiles.mbtiles"
    assert os.path.samestat(linked.stat(), store.stat())
    assert [n for n in report.notes if "hard link" in n and str(store) in n], report.notes


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _candidates(dataset: Path) -> list[list[Any]]:
    """Each frame's candidates, with the pixels of the first as the dataset's store serves them."""
    d = load_dataset(dataset)
    with d.open_store() as store:
        first = d.rerank(d.frames[0], store).candidates[0].tile_pixels_handle.decode()
        return [[c.tile_id for c in f.candidates] for f in d.frames] + [[first.tobytes()]]


@pytest.mark.parametrize("code", [errno.EXDEV, errno.EPERM, errno.EOPNOTSUPP])
def test_where_a_link_is_refused_the_store_is_copied(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, code: int
) -> None:
    """Another filesystem (EXDEV), links refused (EPERM: protected links), a filesystem without
    them (EOPNOTSUPP): the dataset holds a copy, which reads as the linked one does."""
    store = _users_store(tmp_path)
    spec = _flight(tmp_path, store)
    import_csv_flight(spec, tmp_path / "linked")

    def refused(src: object, dst: object, **kw: object) -> None:
        raise OSError(code, os.strerror(code), str(src), None, str(dst))

    monkeypatch.setattr(os, "link", refused)
    report = import_csv_flight(spec, tmp_path / "copied", name="linked")
    copy = tmp_path / "copied" / "tiles.mbtiles"
    assert not os.path.samestat(copy.stat(), store.stat()) and _sha(copy) == _sha(store)
    assert [n for n in report.notes if "a copy of" in n and os.strerror(code) in n], report.notes
    assert _candidates(tmp_path / "copied") == _candidates(tmp_path / "linked")


def test_a_rebuilt_or_deleted_store_leaves_the_dataset_as_it_was(tmp_path: Path) -> None:
    """``tiles build --force`` replaces a store by a rename: the dataset keeps the old file."""
    store = _users_store(tmp_path)
    import_csv_flight(_flight(tmp_path, store), tmp_path / "flight")
    before, candidates = _sha(store), _candidates(tmp_path / "flight")
    with MBTilesWriter(store, overwrite=True) as rebuilt:
        rebuilt.put_tile(ZOOM, 7358, 11522, b"another map")
    assert _sha(store) != before
    assert _sha(tmp_path / "flight" / "tiles.mbtiles") == before
    store.unlink()
    assert _sha(tmp_path / "flight" / "tiles.mbtiles") == before
    assert _candidates(tmp_path / "flight") == candidates
