"""Hostile input at the doors the user's files come in by: a ``--calibration`` or ``--config``
that is a FIFO (waited on for ever), a calibration JSON nested too deep, holding a number too
long to convert or a key twice, a principal point far outside the image, a lens that overflows,
a flight-data log with such a line, and more ``--tile`` than the placeholder ids counted to.
Each is bad input named at once (exit 2), never a hang, an internal error or a silent choice."""

from __future__ import annotations

import json
import os
import subprocess
import uuid
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.dto import CameraCalibration
from c3_matcher.errors import InvalidInputError
from c3_matcher.fdr.check import check_fdr
from c3_matcher.fdr.records import read_fdr
from c3_matcher.georef import is_georeferenced
from c3_matcher.match_inputs import MAX_PLACEHOLDER_TILES, file_candidates
from c3_matcher.serialize import load_calibration

from .demo_match import DEMO, DEMO_MATCH, run_match

DEMO_CALIBRATION = json.loads((DEMO / "calibration.json").read_text())
NESTED = "[" * 100_000 + "]" * 100_000
_FRAME = uuid.UUID(int=1)


def _calibration(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "calibration.json"
    path.write_text(text)
    return path


def _with(**values: object) -> str:
    """The demo calibration's JSON with ``values`` in place of its own."""
    return json.dumps({**DEMO_CALIBRATION, **values})


def _run(argv: list[str]) -> subprocess.CompletedProcess[str]:
    """``c3-matcher argv`` in a child process (a hang is ``TimeoutExpired``, failing the test)."""
    try:
        return run_match(argv=argv)
    except subprocess.TimeoutExpired:
        pytest.fail(f"c3-matcher {' '.join(argv)} hung")


def test_a_calibration_that_is_a_fifo_is_refused_unopened(tmp_path: Path) -> None:
    fifo = tmp_path / "calibration.json"
    os.mkfifo(fifo)
    argv = [*DEMO_MATCH[: DEMO_MATCH.index("--calibration")], "--calibration", str(fifo)]
    out = _run(argv)
    assert out.returncode == 2, out.stderr
    assert out.stderr.strip().splitlines()[-1] == (
        f"c3-matcher: --calibration {fifo}: is a FIFO, not a calibration JSON file"
    )


def test_a_config_that_is_a_fifo_is_refused_unopened(tmp_path: Path) -> None:
    fifo = tmp_path / "c3.toml"
    os.mkfifo(fifo)
    out = _run(["--config", str(fifo), "config"])
    assert out.returncode == 2, out.stderr
    assert "--config: is a FIFO, not a configuration file" in out.stderr


@pytest.mark.parametrize(
    ("text", "why"),
    [
        (NESTED, "unreadable: nested too deep to read"),
        (
            _with(image_size="IMAGE_SIZE").replace('"IMAGE_SIZE"', f"[{'6' * 5001}, 480]"),
            "value has 5001 digits",
        ),
    ],
    ids=["nested", "digits"],
)
def test_a_calibration_json_python_cannot_read_is_bad_input(
    tmp_path: Path, text: str, why: str
) -> None:
    path = _calibration(tmp_path, text)
    with pytest.raises(InvalidInputError, match=f"--calibration {path}") as refused:
        load_calibration(path)
    assert why in refused.value.reason and "sys." not in refused.value.reason


def test_a_key_given_twice_in_a_calibration_is_refused_naming_it(tmp_path: Path) -> None:
    identity = '"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], '
    path = _calibration(tmp_path, "{" + identity + _with()[1:])
    with pytest.raises(InvalidInputError) as refused:
        load_calibration(path)
    assert refused.value.reason == 'key "K" given twice (which one is meant? give it once)'


@pytest.mark.parametrize(("cx", "cy"), [(2000.0, 237.5), (1e6, 237.5), (323.0, -481.0)])
def test_a_principal_point_far_outside_the_image_is_refused_naming_k(
    tmp_path: Path, cx: float, cy: float
) -> None:
    path = _calibration(tmp_path, _with(K=[[560.0, 0, cx], [0, 560.0, cy], [0, 0, 1]]))
    with pytest.raises(InvalidInputError, match="calibration.K: principal point") as refused:
        load_calibration(path)
    assert "outside the 640x480 px image" in refused.value.reason


@pytest.mark.parametrize(("cx", "cy"), [(-640.0, 960.0), (1280.0, -480.0), (0.0, 479.0)])
def test_a_principal_point_off_centre_within_an_image_of_it_is_taken(cx: float, cy: float) -> None:
    k = np.array([[560.0, 0, cx], [0, 560.0, cy], [0, 0, 1]])
    assert CameraCalibration(k, np.zeros(5), (640, 480)).K[0, 2] == cx


def test_a_lens_that_overflows_is_one_line_without_numpy_warnings(tmp_path: Path) -> None:
    path = _calibration(tmp_path, _with(distortion=[0.1] * 8))
    argv = [*DEMO_MATCH[: DEMO_MATCH.index("--calibration")], "--calibration", str(path)]
    out = _run([*argv, *DEMO_MATCH[DEMO_MATCH.index("--calibration") + 2 :]])
    assert out.returncode == 2, out.stderr
    assert "Warning" not in out.stderr, out.stderr
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith(f"c3-matcher: calibration.distortion: {[0.1] * 8} leaves the edge")


def _record(seq: int | str) -> str:
    return (
        f'{{"seq":{seq},"kind":"k","recorded_at_ns":1,"wall_time":"2026-01-01T00:00:00+00:00",'
        '"payload":{}}'
    )


@pytest.mark.parametrize(
    ("line", "why"),
    [(NESTED, "not JSON: nested too deep to read"), (_record("9" * 5001), "value has 5001 digits")],
    ids=["nested", "digits"],
)
def test_an_fdr_line_python_cannot_read_is_named_and_the_rest_read(
    tmp_path: Path, line: str, why: str
) -> None:
    path = tmp_path / "fdr.jsonl"
    path.write_text(f"{_record(1)}\n{line}\n{_record(2)}\n")
    assert [(n, why in r) for n, _, r in read_fdr(path).corrupt] == [(2, True)]
    check = check_fdr(path)
    assert check.records == 2 and not check.intact
    (unreadable,) = check.unreadable
    assert unreadable.startswith("fdr.jsonl:2: not JSON: ") and why in unreadable
    assert "sys." not in unreadable


def test_a_log_whose_state_files_nest_too_deep_is_still_checked(tmp_path: Path) -> None:
    """The ``.meta`` state and the lock file's note are the recorder's, but only files: a
    damaged one is read as none, as any other unreadable one is."""
    path = tmp_path / "fdr.jsonl"
    path.write_text(f"{_record(1)}\n")
    (tmp_path / "fdr.jsonl.meta").write_text(NESTED)
    (tmp_path / "fdr.jsonl.lock").write_text("123\n" + "[" * 1015 + "\n")
    check = check_fdr(path)
    assert (check.records, check.intact, check.not_in_log) == (1, True, None)


def test_an_fdr_path_that_is_a_fifo_is_named_as_one(tmp_path: Path) -> None:
    fifo = tmp_path / "fdr.jsonl"
    os.mkfifo(fifo)
    with pytest.raises(InvalidInputError, match=f"{fifo} is a FIFO, not a flight-data log"):
        check_fdr(fifo)


def test_each_tile_without_an_id_has_its_own_placeholder_past_180() -> None:
    tiles = [DEMO / "tile_a.png"] * 200
    ids = [c.tile_id for c in file_candidates(_FRAME, tiles, [], None, 1 << 24).candidates]
    assert len(set(ids)) == 200 and not any(is_georeferenced(t) for t in ids)
    assert [t.as_list() for t in ids[:2]] == [[0, 0.0, 0.0], [0, 0.0, 1.0]]
    assert ids[181].as_list() == [0, 1.0, 0.0]


def test_more_tiles_without_ids_than_placeholders_are_refused_naming_tile() -> None:
    tiles = [DEMO / "tile_a.png"] * (MAX_PLACEHOLDER_TILES + 1)
    with pytest.raises(InvalidInputError, match="--tile: .* at most .* give one --tile-id"):
        file_candidates(_FRAME, tiles, [], None, 1 << 24)
