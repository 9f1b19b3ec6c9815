"""An eval on a damaged tile store does not read as a sound one: a frame without its true tile
whose every candidate was dropped for its tile is no C3-IT-05 pass (the matcher saw no tile to
refuse), each ``summary.json`` row carries the candidates dropped for their tiles, and with
``--json`` the line that says the store is damaged goes to stderr (two-frame flights,
``sift_magsac``)."""

from __future__ import annotations

import json
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

from .test_dropped_candidates_report import _corrupt_every_tile

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
C3 = Callable[..., subprocess.CompletedProcess[str]]
DEMO = Path(__file__).resolve().parents[3] / "data" / "flights" / "naip_demo"
ABSENT = 13  # a demo frame whose true tile is not among its candidates


def _with_an_absent_frame(flight: Path) -> Path:
    """``flight``'s second frame replaced by the demo's frame ``ABSENT`` (true tile absent)."""
    lines = (flight / "frames.jsonl").read_text().splitlines()
    absent = (DEMO / "frames.jsonl").read_text().splitlines()[ABSENT]
    shutil.copyfile(DEMO / json.loads(absent)["image"], flight / json.loads(absent)["image"])
    (flight / "frames.jsonl").write_text(f"{lines[0]}\n{absent}\n")
    return flight


def test_a_damaged_store_gives_no_it05_pass_and_says_so_in_the_json(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    damaged = _with_an_absent_frame(small_flight("damaged"))
    store = damaged / "tiles.mbtiles"
    _corrupt_every_tile(store)
    intact = small_flight("intact", where="intact")
    out = tmp_path / "ev"
    proc = c3(
        "eval", str(damaged), str(intact), "--strategy", "sift_magsac", "--no-baseline",
        "--determinism-frames", "1", "--samples", "0", "--out", str(out), "--json",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    document = json.loads(proc.stdout)  # stdout is the JSON alone
    it05 = document["flights"][0]["strategies"][0]["metrics"]["C3-IT-05"]
    assert it05["pass"] is not True, it05  # no tile was read: no evidence of a refusal
    assert it05["insufficient"] == 0 and it05["tiles_unread_frames"] == [ABSENT], it05
    rows = {r["flight"]: r for r in json.loads((out / "summary.json").read_text())}
    assert (rows["damaged"]["tile_dropped"], rows["damaged"]["candidates"]) == (6, 6)
    assert rows["intact"]["tile_dropped"] == 0 and rows["intact"]["candidates"] == 6
    assert rows["damaged"]["it05_raised"] == 0, rows["damaged"]
    assert document["summary"] == list(rows.values())
    said = (
        "c3-matcher eval: sift_magsac on damaged: 6 of 6 candidates were dropped for their "
        f"tiles: the tile store {store} is damaged"
    )
    assert any(line.startswith(said) for line in proc.stderr.splitlines()), proc.stderr
    assert "intact" not in proc.stderr, proc.stderr
