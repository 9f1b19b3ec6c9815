"""``features build|info`` against the store's tiles as they are now: ``info --verify`` counts a
window whose tiles changed since it was built as stale (the flight serves it no more) and exits
1; a resumed build skips a window over a tile stored with NULL data (digested as the worker and
the flight digest it); a ``--window`` the strategy's input rule would pad or resize is refused in
one line before the sidecar is touched. XFeat in process, on a few windows of the demo store."""

from __future__ import annotations

import hashlib
import json
import shutil
import sqlite3
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
ZOOM, X, Y = 15, 7358, 11522  # an XYZ tile inside the demo store (7 x 5 tiles at zoom 15)
ROW = (1 << ZOOM) - 1 - Y  # its MBTiles (TMS) row


@pytest.fixture()
def store(tmp_path: Path, engine_dir: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    path = tmp_path / "tiles.mbtiles"
    shutil.copy(FLIGHT / "tiles.mbtiles", path)
    return path


def _build(store: Path, windows: list[tuple[int, int, int]], stride: int) -> dict[str, Any]:
    from c3_matcher.config import load_settings
    from c3_matcher_tools.features.build import build_features

    report = build_features(
        store, ["xfeat"], load_settings(None), window_px=256, stride_px=stride, windows=windows,
        workers=0, progress=lambda line: None,
    )  # fmt: skip
    return report.strategies["xfeat"]


def _verified(store: Path, capsys: pytest.CaptureFixture[str], code: int) -> dict[str, Any]:
    from c3_matcher.cli import main

    capsys.readouterr()
    assert main(["features", "info", str(store), "--verify", "--json"]) == code
    (found,) = json.loads(capsys.readouterr().out)["sets"]
    return dict(found)


@pytest.mark.slow
def test_verify_counts_windows_whose_tiles_changed_as_stale_and_exits_1(
    store: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    windows = [(ZOOM, X, Y), (ZOOM, X + 1, Y)]
    assert _build(store, windows, 256)["extracted"] == 2
    found = _verified(store, capsys, 0)
    assert (found["intact"], found["damaged"], found["stale"]) == (2, 0, 0)
    with sqlite3.connect(store) as db:  # every tile rewritten, its recorded sha256 with it
        for col, row, blob in db.execute("SELECT tile_column, tile_row, tile_data FROM tiles"):
            new = bytes(blob) + b"\0"  # after the JPEG's end: the same pixels, other bytes
            db.execute(
                "UPDATE tiles SET tile_data=? WHERE tile_column=? AND tile_row=?", (new, col, row)
            )
            db.execute(
                "UPDATE c3_tile_digest SET sha256=? WHERE tile_column=? AND tile_row=?",
                (hashlib.sha256(new).hexdigest(), col, row),
            )
    found = _verified(store, capsys, 1)
    assert (found["complete"], found["intact"], found["damaged"], found["stale"]) == (
        True, 0, 0, 2,
    )  # fmt: skip
    assert main(["features", "info", str(store), "--verify"]) == 1
    said = capsys.readouterr()
    assert "stale: 2" in said.out
    assert f"{store}.features.sqlite: 2 stale windows" in said.err, said.err
    assert f"c3-matcher features build {store}" in said.err
    assert _build(store, windows, 256)["extracted"] == 2  # extracted again: current now
    found = _verified(store, capsys, 0)
    assert (found["intact"], found["stale"]) == (2, 0)


@pytest.mark.slow
def test_a_resumed_build_skips_windows_over_a_tile_stored_with_null_data(
    store: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with sqlite3.connect(store) as db:  # a tile row with no data (and no sha256): no tile
        db.execute("UPDATE tiles SET tile_data=NULL WHERE tile_column=? AND tile_row=?", (X, ROW))
        db.execute("DELETE FROM c3_tile_digest WHERE tile_column=? AND tile_row=?", (X, ROW))
    windows = [(ZOOM, 2 * X - 1, 2 * Y), (ZOOM, 2 * X + 1, 2 * Y)]  # half over it, half not
    assert _build(store, windows, 128)["extracted"] == 2
    again = _build(store, windows, 128)
    assert (again["skipped"], again["extracted"]) == (2, 0)
    found = _verified(store, capsys, 0)  # and current, as the flight digests them
    assert (found["intact"], found["stale"]) == (2, 0)


def test_check_window_is_the_input_rule() -> None:
    from c3_matcher.errors import InvalidInputError
    from c3_matcher.prepared import InputRule
    from c3_matcher_tools.features.worker import check_window

    rule = InputRule(max_long_side=1024, multiple=32)
    for fits in (32, 256, 1024):
        check_window(rule, fits)
    for size, why in ((300, "multiple of 32"), (1056, "at most 1024")):
        with pytest.raises(InvalidInputError, match=why) as caught:
            check_window(rule, size, "xfeat")
        assert caught.value.field == "--window" and f"{size} px" in str(caught.value)


@pytest.mark.parametrize("workers", ["0", pytest.param("1", marks=pytest.mark.slow)])
def test_a_window_the_input_rule_would_pad_is_refused_before_the_sidecar_is_touched(
    workers: str, store: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """Refused in one line (no worker's traceback), nothing left in the sidecar."""
    from c3_matcher.cli import main

    argv = ["features", "build", str(store), "--strategy", "xfeat", "--window", "300"]
    assert main([*argv, "--workers", workers]) == 2
    err = capfd.readouterr().err.strip()
    assert "features build: --window: 300 px would be padded or resized" in err, err
    assert "a window must be a multiple of 32 px and at most" in err, err
    assert len(err.splitlines()) == 1, err
    assert not (store.parent / "tiles.mbtiles.features.sqlite").exists()


class _ScaleForgotten:
    """The strategy's backend, but its keypoints at twice their place (a scale forgotten)."""

    def __init__(self, backend: Any) -> None:
        self._backend = backend

    def __getattr__(self, name: str) -> Any:
        return getattr(self._backend, name)

    def extract(self, image: Any) -> Any:
        import dataclasses

        found = self._backend.extract(image)
        return dataclasses.replace(found, keypoints=found.keypoints * 2 + 8)


def test_a_build_stores_no_window_whose_keypoints_fall_off_it(
    store: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What the flight would refuse on extraction is refused before it is stored, naming it."""
    from c3_matcher.errors import InvalidInputError
    from c3_matcher_tools.features import worker

    backend_of = worker._backend
    monkeypatch.setattr(worker, "_backend", lambda *a: _ScaleForgotten(backend_of(*a)))
    with pytest.raises(InvalidInputError, match=r"keypoint\(s\) outside the 256x256 px"):
        _build(store, [(ZOOM, 2 * X + 1, 2 * Y)], 128)
