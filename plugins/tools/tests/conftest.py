"""Fixtures the tools' command tests share: ``small_flight``, a two-frame cut of the shipped demo
flight under a name of the test's choosing, and ``c3``, the command line in a subprocess run from
a directory of the test's choosing (the classical ``sift_magsac`` baseline needs no engines)."""

from __future__ import annotations

import json
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from c3_matcher_tools.testing.cli import run_cli

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
DEMO_CALIBRATION = str(DEMO / "calibration.json")
DEMO_STORE = str(DEMO / "tiles.mbtiles")


def run_in_repo(*args: str | Path) -> subprocess.CompletedProcess[str]:
    """``c3-matcher ARGS`` in a subprocess run from the checkout (its demo data's paths)."""
    return run_cli(*args, cwd=REPO)


SmallFlight = Callable[..., Path]
Record = dict[str, Any]
"""A JSON object of a dataset's files, as read."""


def edit_frame_record(root: Path, line: int, edit: Callable[[Record], None]) -> None:
    """The record on ``line`` (from 1) of the dataset ``root``'s ``frames.jsonl`` changed by
    ``edit``, in place."""
    path = root / "frames.jsonl"
    records = [json.loads(x) for x in path.read_text().splitlines()]
    edit(records[line - 1])
    path.write_text("".join(json.dumps(r) + "\n" for r in records))


def edit_dataset_meta(root: Path, edit: Callable[[Record], None]) -> None:
    """The dataset ``root``'s ``dataset.json`` changed by ``edit``, in place."""
    meta = json.loads((root / "dataset.json").read_text())
    edit(meta)
    (root / "dataset.json").write_text(json.dumps(meta))


C3 = Callable[..., subprocess.CompletedProcess[str]]


def _small_flight(where: Path, name: str, *, without_image: int | None = None) -> Path:
    """The first two frames of the demo flight at ``where``, named ``name`` in its
    dataset.json; ``without_image``: that frame's image left out."""
    where.mkdir(parents=True)
    for file in ("calibration.json", "tiles.mbtiles"):
        shutil.copyfile(DEMO / file, where / file)
    meta = json.loads((DEMO / "dataset.json").read_text())
    (where / "dataset.json").write_text(json.dumps({**meta, "name": name}))
    lines = (DEMO / "frames.jsonl").read_text().splitlines()[:2]
    (where / "frames.jsonl").write_text("\n".join(lines) + "\n")
    (where / "frames").mkdir()
    for n, line in enumerate(lines):
        image = json.loads(line)["image"]
        if n != without_image:
            shutil.copyfile(DEMO / image, where / image)
    return where


@pytest.fixture()
def small_flight(tmp_path: Path) -> SmallFlight:
    """``small_flight(name, *, where="flight", without_image=None)``: a two-frame dataset."""

    def make(name: str, *, where: str = "flight", without_image: int | None = None) -> Path:
        return _small_flight(tmp_path / where, name, without_image=without_image)

    return make


@pytest.fixture()
def c3(tmp_path: Path) -> C3:
    """``c3(*args, cwd=tmp_path)``: ``c3-matcher ARGS`` in a subprocess, without the caller's
    ``C3_MATCHER_*`` settings; ``limit_file_bytes`` caps the size of any file it writes."""

    def run(
        *args: str, cwd: Path = tmp_path, limit_file_bytes: int | None = None
    ) -> subprocess.CompletedProcess[str]:
        return run_cli(*args, cwd=cwd, timeout=600, limit_file_bytes=limit_file_bytes)

    return run


@pytest.fixture()
def no_bench_case(monkeypatch: pytest.MonkeyPatch) -> None:
    """``bench`` fails the test if it gets as far as running a case (its checks must refuse
    first)."""
    import c3_matcher_tools.bench

    def no_case(*args: object, **kwargs: object) -> None:
        raise AssertionError("a case ran")

    monkeypatch.setattr(c3_matcher_tools.bench, "cases_for", no_case)


def stored_tiles(store: Path) -> dict[tuple[int, int, int], Any]:
    """Every tile of the MBTiles ``store`` decoded (BGR, as OpenCV reads), by (zoom, x, y)
    (XYZ rows)."""
    import cv2
    import numpy as np

    from c3_matcher.tilestore.mbtiles import MBTilesStore

    out = {}
    with MBTilesStore(store) as st:
        for z in st.zooms():
            for x, y in st.tiles(z):
                data = st.tile_bytes(z, x, y)
                assert data is not None
                out[(z, x, y)] = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    return out
