"""The stored map features serve every thread, not only the one whose frame opened the sidecar
(a flight loop in a thread of its own after a start-up check on the main thread); an error the
sqlite3 module raises itself (no SQLite result code: a closed connection, a misuse) is the
store's one ``FeatureStoreUnavailableError`` per outage, or the writer's own error, never an
AttributeError. The demo flight's real tile store, with features written through the
sidecar's own writer (as in test_stored_features.py)."""

from __future__ import annotations

import sqlite3
import threading
from typing import Any

import numpy as np
import pytest

from c3_matcher.tilestore.features import (
    FeatureStoreUnavailableError,
    MapFeatureStore,
    sidecar_path,
)
from c3_matcher.tilestore.mbtiles import MBTilesStore

from .test_stored_features import FSET, STRIDE, ZOOM, _serve, store  # noqa: F401  (a fixture)


@pytest.fixture
def served(store: tuple[MBTilesStore, tuple[int, int]]) -> tuple[MBTilesStore, tuple[int, int]]:  # noqa: F811
    """The demo store copy with one stored window (``store``); its grid origin in world px."""
    source, (gx, gy) = store
    return source, (gx * STRIDE, gy * STRIDE)


def _in_thread(source: MBTilesStore, origin: tuple[int, int]) -> dict[str, Any]:
    got: dict[str, Any] = {}

    def serve() -> None:
        try:
            got["features"] = _serve(source, origin)
        except Exception as exc:  # what the matcher would log as a WARNING
            got["error"] = exc

    thread = threading.Thread(target=serve)
    thread.start()
    thread.join(30)
    return got


def test_stored_features_are_served_to_threads_other_than_the_one_that_opened_them(served):
    source, origin = served
    first = _serve(source, origin)  # opens the sidecar on this thread (the start-up check)
    assert first is not None
    for _ in range(2):  # the flight loop's thread, then another
        got = _in_thread(source, origin)
        assert "error" not in got, got.get("error")
        assert got["features"] is not None
        assert np.array_equal(got["features"].descriptors, first.descriptors)
        assert np.array_equal(got["features"].keypoints, first.keypoints)


def test_a_read_the_sqlite3_module_refuses_is_one_outage_not_an_attribute_error(served):
    source, (x0, y0) = served
    side = MapFeatureStore(sidecar_path(source.path))
    fset = side.feature_set(FSET.set_id)
    assert fset is not None
    side.close()  # the module refuses a closed connection itself: ProgrammingError, no code
    with pytest.raises(FeatureStoreUnavailableError, match="ProgrammingError.*closed database"):
        side.window(fset, ZOOM, x0 // STRIDE, y0 // STRIDE)
    assert side.window(fset, ZOOM, x0 // STRIDE, y0 // STRIDE) is None  # said once


def test_the_writer_raises_the_modules_own_error_as_it_is(served):
    source, _ = served
    writer = MapFeatureStore(sidecar_path(source.path), writable=True)
    writer.close()
    with pytest.raises(sqlite3.ProgrammingError, match="closed database"):
        writer.done_windows(FSET.set_id)
