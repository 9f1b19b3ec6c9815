"""``c3-matcher dataset import`` of a recorded flight that the tile store covers only in part,
as an orthophoto of the mission area that leaves out the take-off or a transit does: the 30
frames of the shipped demo flight as a PX4 ULog (the project's own writer) with their photos,
and the shipped store without the tiles of its eastern columns, which 10 of the frames look
into. By default the import is refused, saying how many frames are inside and which option
imports them; with ``--skip-outside`` the frames outside are skipped and listed with the reason,
and a flight of which no frame is inside is refused still."""

from __future__ import annotations

import json
import shutil
import sqlite3
import subprocess
from pathlib import Path

import pytest

from c3_matcher_tools.dataset.format import load_dataset
from c3_matcher_tools.testing import flightlogs as fl
from c3_matcher_tools.testing.cli import run_cli
from c3_matcher_tools.testing.flightlogs.ulog import write_ulog

REPO = Path(__file__).resolve().parents[3]
DEMO = REPO / "data" / "flights" / "naip_demo"
CAL = str(DEMO / "calibration.json")
EAST_COLUMN = 7359
"""The shipped store's zoom-15 tiles from this column east hold the look points of
:data:`OUTSIDE`."""
OUTSIDE = [9, 10, 11, 12, 13, 15, 17, 19, 20, 21]


def c3(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return run_cli("dataset", "import", *args, cwd=REPO)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding ``photos/`` (IMG_0000.jpg ...) and ``flight.ulg``: the demo flight."""
    root = tmp_path_factory.mktemp("recorded")
    poses = fl.flight_poses(DEMO, range(30))
    (root / "photos").mkdir()
    for i, p in enumerate(poses):
        shutil.copyfile(p.image, root / "photos" / f"IMG_{i:04d}.jpg")
    write_ulog(root / "flight.ulg", poses)
    return root


def _store_without_columns(root: Path, first: int, last: int = 1 << 15) -> Path:
    """The shipped store without its tiles in columns ``first`` .. ``last``: a store built from
    an orthophoto that ends there."""
    store = root / "part.mbtiles"
    shutil.copyfile(DEMO / "tiles.mbtiles", store)
    db = sqlite3.connect(store)
    with db:
        for table in ("tiles", "c3_tile_digest"):
            db.execute(
                f"DELETE FROM {table} WHERE tile_column BETWEEN ? AND ?",
                (first, last),
            )
    db.close()
    return store


def _one_line(proc: subprocess.CompletedProcess[str]) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr[-2000:])
    lines = [x for x in proc.stderr.splitlines() if x.strip()]
    assert len(lines) == 1, proc.stderr
    return lines[0]


def test_a_flight_partly_outside_the_store_is_refused_naming_those_inside_and_the_option(
    recorded: Path, tmp_path: Path
) -> None:
    store = _store_without_columns(tmp_path, EAST_COLUMN)
    out = tmp_path / "flight"
    proc = c3(recorded / "photos", recorded / "flight.ulg", CAL, store, out)
    line = _one_line(proc)
    assert "flight.ulg: 10 of 30 frame(s) look outside the store's coverage at zoom 15" in line
    assert "IMG_0009.jpg (looks at " in line and "and 5 more" in line
    assert "give --skip-outside to import the 20 inside" in line
    assert "different places" not in line  # two thirds of the flight is over the store
    assert not out.exists()


def test_with_skip_outside_the_frames_outside_are_skipped_and_listed(
    recorded: Path, tmp_path: Path
) -> None:
    store = _store_without_columns(tmp_path, EAST_COLUMN)
    out = tmp_path / "flight"
    args = ["--skip-outside", "--json"]
    proc = c3(recorded / "photos", recorded / "flight.ulg", CAL, store, out, *args)
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads(proc.stdout)
    assert summary["frames"] == 20
    names = [f"IMG_{i:04d}.jpg" for i in OUTSIDE]
    assert [s["image"] for s in summary["skipped"]] == names
    for s in summary["skipped"]:
        assert "look point (47.0" in s["reason"], s
        assert s["reason"].endswith("outside the store's coverage at zoom 15"), s
    d = load_dataset(out)
    kept = [f.telemetry["source_image"] for f in d.frames]
    assert kept == [f"IMG_{i:04d}.jpg" for i in range(30) if i not in OUTSIDE]
    assert [f.index for f in d.frames] == list(range(20))
    assert d.meta["spec"]["skip_outside"] is True
    said = c3(recorded / "photos", recorded / "flight.ulg", CAL, store, tmp_path / "again")
    assert said.returncode == 2  # the default is the refusal: nothing dropped unasked
    first = summary["skipped"][0]["reason"].split("look point (")[1].split(")")[0]
    assert f"{names[0]} (looks at {first})" in said.stderr  # one place, said alike


def test_with_skip_outside_a_flight_wholly_outside_the_store_is_refused_still(
    recorded: Path, tmp_path: Path
) -> None:
    store = _store_without_columns(tmp_path, EAST_COLUMN - 1, EAST_COLUMN)
    out = tmp_path / "flight"
    proc = c3(recorded / "photos", recorded / "flight.ulg", CAL, store, out, "--skip-outside")
    line = _one_line(proc)
    assert "flight.ulg: 30 frame(s) look outside the store's coverage at zoom 15" in line
    assert "(log and store of different places?)" in line
    assert "--skip-outside" not in line  # it cannot help
    assert not out.exists()


def test_the_option_is_in_the_help() -> None:
    proc = run_cli("dataset", "import", "--help", cwd=REPO)
    assert proc.returncode == 0
    assert "--skip-outside" in proc.stdout


def test_a_telemetry_csv_partly_outside_the_store_is_refused_or_skipped_alike(
    recorded: Path, tmp_path: Path
) -> None:
    """The telemetry CSV's import makes the same refusal, naming CSV lines, and takes the same
    option."""
    poses = fl.flight_poses(DEMO, range(30))
    rows = ["time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg"]
    rows += [
        f"{p.t_s},IMG_{i:04d}.jpg,{p.lat},{p.lon},{p.height_m},{p.roll},{p.pitch},{p.yaw}"
        for i, p in enumerate(poses)
    ]
    csv = tmp_path / "telemetry.csv"
    csv.write_text("\n".join(rows) + "\n")
    store = _store_without_columns(tmp_path, EAST_COLUMN)
    line = _one_line(c3(recorded / "photos", csv, CAL, store, tmp_path / "refused"))
    assert "TELEMETRY: 10 of 30 frame(s) look outside the store's coverage at zoom 15" in line
    assert "line 11 (" in line and "give --skip-outside to import the 20 inside" in line
    out = tmp_path / "flight"
    proc = c3(recorded / "photos", csv, CAL, store, out, "--skip-outside", "--json")
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads(proc.stdout)
    assert summary["frames"] == 20
    assert [s["image"] for s in summary["skipped"]] == [f"IMG_{i:04d}.jpg" for i in OUTSIDE]
    kept = [f.telemetry["source_image"] for f in load_dataset(out).frames]
    assert kept == [f"IMG_{i:04d}.jpg" for i in range(30) if i not in OUTSIDE]
