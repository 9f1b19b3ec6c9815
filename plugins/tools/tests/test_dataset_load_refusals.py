"""``load_dataset`` checks what it reads before any frame is used: a malformed dataset.json or
frame record is refused naming the file (and the line of frames.jsonl), never an internal error
later in a run; a dataset without frames is refused."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from c3_matcher.cli import main
from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import load_dataset

from .conftest import DEMO, Record, edit_dataset_meta, edit_frame_record

DEMO_FIRST = (DEMO / "frames.jsonl").read_text().splitlines()[0]


def _dataset(root: Path) -> Path:
    """The demo's dataset.json, calibration and first two frame records; the store a
    placeholder (loading only checks it is there)."""
    root.mkdir()
    for name in ("dataset.json", "calibration.json"):
        shutil.copyfile(DEMO / name, root / name)
    (root / "tiles.mbtiles").write_bytes(b"")
    lines = (DEMO / "frames.jsonl").read_text().splitlines()[:2]
    (root / "frames.jsonl").write_text("\n".join(lines) + "\n")
    return root


@pytest.mark.parametrize(
    ("line", "edit", "needle"),
    [
        (1, lambda r: r.update(index=-1), "index: must be in [0, "),
        (2, lambda r: r.update(height_m=float("nan")), "height_m: must be finite"),
        (2, lambda r: r.update(height_m=-5), "height_m: must be > 0"),
        (
            1,
            lambda r: r.update(telemetry={"lat": "x", "lon": 5}),
            "telemetry.lat: expected a number",
        ),
        (2, lambda r: r["pose"].update(footprint_centre_lat=123.0), "pose.footprint_centre_lat"),
        (
            1,
            lambda r: r.update(attitude_deg=[95.0, 0.0, 0.0]),
            "attitude_deg: [95.0, 0.0, 0.0] out",
        ),
        (2, lambda r: r.update(candidates=[]), "candidates: expected a non-empty list"),
        (1, lambda r: r["candidates"][0].update(score=float("nan")), "candidate.score"),
        (2, lambda r: r.update(captured_at_ns=-5), "captured_at_ns"),
        (2, lambda r: r.update(index=0), "index: 0 is line 1's too"),
        (
            2,
            lambda r: r.update(frame_id=json.loads(DEMO_FIRST)["frame_id"]),
            "frame_id: ",
        ),
    ],
)
def test_a_bad_frame_record_is_refused_naming_its_line(
    tmp_path: Path, line: int, edit: Callable[[Record], None], needle: str
) -> None:
    root = _dataset(tmp_path / "flight")
    edit_frame_record(root, line, edit)
    with pytest.raises(InvalidInputError) as refused:
        load_dataset(root)
    assert f"frames.jsonl:{line}: bad frame record: {needle}" in str(refused.value)


def test_frames_that_are_not_utf8_are_refused_naming_the_line(tmp_path: Path) -> None:
    root = _dataset(tmp_path / "flight")
    with (root / "frames.jsonl").open("ab") as fh:
        fh.write(b'\xff\xfe{"index": 2}\n')
    with pytest.raises(InvalidInputError, match=r"frames\.jsonl:3: bad frame record: Unicode"):
        load_dataset(root)


@pytest.mark.parametrize(
    ("write", "needle"),
    [
        (lambda root: (root / "dataset.json").write_text("[1, 2]"), "top level: expected a JSON"),
        (lambda root: (root / "dataset.json").write_bytes(b"\xff\xfe{"), "UnicodeDecodeError"),
        (
            lambda root: edit_dataset_meta(root, lambda m: m.update(candidate_size_px="abc")),
            "candidate_size_px: expected an integer",
        ),
        (
            lambda root: edit_dataset_meta(root, lambda m: m.update(candidate_size_px=0)),
            "candidate_size_px: must be in [64, 4096]",
        ),
        (lambda root: edit_dataset_meta(root, lambda m: m.update(store=None)), "store: expected a"),
    ],
)
def test_a_bad_dataset_json_is_refused_naming_the_file(
    tmp_path: Path, write: Callable[[Path], None], needle: str
) -> None:
    root = _dataset(tmp_path / "flight")
    write(root)
    with pytest.raises(InvalidInputError) as refused:
        load_dataset(root)
    assert f"dataset.json: {needle}" in str(refused.value)


def test_a_dataset_without_frames_is_refused_with_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root = _dataset(tmp_path / "flight")
    (root / "frames.jsonl").write_text("\n")
    assert main(["dataset", "info", str(root)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"c3-matcher: dataset: {root / 'frames.jsonl'}: no frames"
    )


def test_the_datasets_own_file_given_for_it_names_its_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``dataset info flight/dataset.json`` (or replay, eval, features): the file exists, so
    "no dataset.json" was wrong; the fix is its directory."""
    root = _dataset(tmp_path / "flight")
    assert main(["dataset", "info", str(root / "dataset.json")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"c3-matcher: dataset: {root / 'dataset.json'} is the dataset's file: give its "
        f"directory {root}"
    )


def test_every_shipped_flight_passes_the_checks() -> None:
    for flight in sorted(DEMO.parent.glob("*/dataset.json")):
        assert load_dataset(flight.parent).frames
