"""``tiles build`` writes a per-tile sha256 table; the read path verifies it."""

from __future__ import annotations

import hashlib
import sqlite3
from pathlib import Path

import cv2
import numpy as np
import pytest

from c3_matcher.tilestore.mbtiles import MBTilesStore, TileDigestError
from c3_matcher_tools.tilestore.writer import MBTilesWriter


def test_writer_records_digests_and_reader_refuses_a_corrupt_tile(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    blobs = {}
    path = tmp_path / "s.mbtiles"
    with MBTilesWriter(path) as w:
        for x in range(2):
            img = cv2.GaussianBlur(rng.integers(0, 255, (256, 256, 3), dtype=np.uint8), (7, 7), 2)
            blobs[x] = cv2.imencode(".jpg", img)[1].tobytes()
            w.put_tile(5, x, 3, blobs[x])
    db = sqlite3.connect(path)
    rows = dict(db.execute("SELECT tile_column, sha256 FROM c3_tile_digest").fetchall())
    assert rows == {x: hashlib.sha256(b).hexdigest() for x, b in blobs.items()}
    bad = bytearray(blobs[0])
    bad[len(bad) // 2 : len(bad) // 2 + 200] = bytes(range(200))
    db.execute("UPDATE tiles SET tile_data=? WHERE tile_column=0", (bytes(bad),))
    db.commit()
    db.close()
    with MBTilesStore(path) as store:
        with pytest.raises(TileDigestError, match="tile 5/0/3"):
            store.tile_bytes(5, 0, 3)
        assert bytes(store.tile_bytes(5, 1, 3) or b"") == blobs[1]
