"""What ``features info --verify`` tells a user to run when a set fails its check is the command
that builds THAT set again: its strategy, window and stride, and ``--flight-candidates`` when
the set holds only the windows of the flight it is asked about. Running the printed command
makes ``--verify`` pass. A damaged sidecar file (cut short, or no database at all) is a failure
of the check (exit 1, as for damaged windows), not bad input, and the message names the command
that builds its sets again."""

from __future__ import annotations

import hashlib
import json
import re
import shlex
import sqlite3
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str]:
    from c3_matcher.cli import main

    capsys.readouterr()
    code = main(list(argv))
    return code, capsys.readouterr().err.strip()


@pytest.fixture
def flight(
    small_flight: Callable[..., Path],
    engine_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> Path:
    """A two-frame flight whose xfeat set is built as README says (``--flight-candidates``)."""
    built = small_flight("advice")
    monkeypatch.setenv("C3_MATCHER_ENGINES__DIRECTORY", str(engine_dir))
    build = ["features", "build", str(built), "--strategy", "xfeat", "--workers", "0"]
    assert _run(capsys, *build, "--flight-candidates")[0] == 0
    return built


def _tiles_changed(store: Path) -> None:
    """Every tile of ``store`` brightened and re-encoded, its recorded sha256 with it."""
    with sqlite3.connect(store) as db:
        rows = db.execute("SELECT zoom_level, tile_column, tile_row, tile_data FROM tiles")
        for z, x, y, data in rows.fetchall():
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
            new = cv2.imencode(".jpg", cv2.add(image, 10))[1].tobytes()
            key = (z, x, y)
            db.execute(
                "UPDATE tiles SET tile_data=? WHERE zoom_level=? AND tile_column=? AND tile_row=?",
                (new, *key),
            )
            db.execute(
                "UPDATE c3_tile_digest SET sha256=? "
                "WHERE zoom_level=? AND tile_column=? AND tile_row=?",
                (hashlib.sha256(new).hexdigest(), *key),
            )


def _printed_command(err: str) -> list[str]:
    (command,) = re.findall(r"c3-matcher (features build [^.;()]*?)(?:\.| \(|;|$)", err)
    return shlex.split(command)


@pytest.mark.slow
def test_the_command_printed_for_stale_windows_extracts_them_again(
    flight: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _tiles_changed(flight / "tiles.mbtiles")
    code, err = _run(capsys, "features", "info", str(flight), "--verify")
    assert code == 1 and "stale windows" in err, err
    command = _printed_command(err)
    assert command[:3] == ["features", "build", str(flight)], err
    assert "--strategy xfeat --window 448 --stride 32 --flight-candidates" in err, err
    assert _run(capsys, *command, "--workers", "0")[0] == 0  # where it runs, not what it builds
    code, err = _run(capsys, "features", "info", str(flight), "--verify")
    assert (code, err) == (0, ""), err


@pytest.mark.slow
def test_a_set_given_by_its_store_names_its_window_and_stride(
    flight: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store = flight / "tiles.mbtiles"
    _tiles_changed(store)
    code, err = _run(capsys, "features", "info", str(store), "--verify")
    assert code == 1, err
    assert f"features build {store} --strategy xfeat --window 448 --stride 32" in err, err
    assert "--flight-candidates instead of the store" in err, err  # not recorded: said so


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["cut short", "no database"])
def test_a_damaged_sidecar_is_exit_1_and_names_the_command_for_its_sets(
    damage: str, flight: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sidecar = flight / "tiles.mbtiles.features.sqlite"
    data = sidecar.read_bytes()
    sidecar.write_bytes(data[:100_000] if damage == "cut short" else b"garbage\n" * 100)
    code, err = _run(capsys, "features", "info", str(flight), "--verify")
    assert code == 1 and len(err.splitlines()) == 1, err
    assert str(sidecar) in err and "the flight extracts" in err, err
    assert f"features build {flight} --strategy NAME --window W --stride S" in err, err
    assert f"{sidecar.name}.damaged" in err, err


@pytest.mark.slow
def test_with_json_a_stale_set_carries_the_command_that_extracts_it_again(
    flight: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    info = ["features", "info", str(flight), "--verify", "--json"]
    capsys.readouterr()
    assert main(info) == 0
    document = json.loads(capsys.readouterr().out)
    ((intact,),) = [document["sets"]]
    assert intact["command"] is None and document["problem"] is document["command"] is None
    _tiles_changed(flight / "tiles.mbtiles")
    assert main(info) == 1
    out, err = capsys.readouterr()
    (stale,) = json.loads(out)["sets"]
    assert stale["stale"] > 0 and f"extract them again: {stale['command']}" in err, err
    assert "(" not in stale["command"], stale["command"]  # runnable as it is
    built = f"c3-matcher features build {flight} --strategy xfeat --window 448 --stride 32"
    assert stale["command"].startswith(f"{built} --flight-candidates"), stale["command"]
