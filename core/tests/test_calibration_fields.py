"""A calibration JSON whose value has the wrong type is refused naming the key and the form it
takes (never a Python repr such as ``ValueError("could not convert ...")``), and the caller says
what the file is: ``match``'s ``--calibration PATH``, or ``dataset: PATH`` for a dataset's own
``calibration.json``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.serialize import load_calibration

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo"
SHIPPED = json.loads((DEMO / "calibration.json").read_text())


def _written(tmp_path: Path, **values: Any) -> Path:
    """The demo's calibration with ``values`` replaced."""
    path = tmp_path / "cal.json"
    path.write_text(json.dumps({**SHIPPED, **values}))
    return path


@pytest.mark.parametrize(
    ("values", "said"),
    [
        ({"K": "abc"}, "K: expected a 3x3 list of numbers ([[a, b, c], [d, e, f], [g, h, i]]), "
         "got 'abc'"),
        ({"K": [[560, 0, 323], [0, "560", 237.5], [0, 0, 1]]}, "K: expected a 3x3 list"),
        ({"K": [[560, 0, 323], [0, 560, 237.5]]}, "K: expected a 3x3 list"),
        ({"K": [[True, 0, 0], [0, 1, 0], [0, 0, 1]]}, "K: expected a 3x3 list"),
        ({"image_size": ["a", 480]}, "image_size: expected [width, height] as whole numbers of "
         "px, got ['a', 480]"),
        ({"image_size": [640.5, 480]}, "image_size: expected [width, height] as whole numbers"),
        ({"image_size": "640x480"}, "image_size: expected [width, height]"),
        ({"distortion": None}, "distortion: expected a list of 0, 4, 5, 8, 12 or 14 numbers"),
        ({"distortion": [-0.12, "0.03", 0, 0, 0]}, "distortion: expected a list of 0, 4, 5"),
        ({"camera_to_body": "down"}, "camera_to_body: expected a 3x3 list of numbers"),
        ({"K": [[1e400, 0, 323], [0, 560, 237.5], [0, 0, 1]]}, "calibration.K: contains NaN"),
        ({"K": [[10**400, 0, 323], [0, 560, 237.5], [0, 0, 1]]}, "K: a number beyond float"),
    ],
)  # fmt: skip
def test_a_wrong_typed_value_names_the_key_and_its_form(
    tmp_path: Path, values: dict[str, Any], said: str
) -> None:
    path = _written(tmp_path, **values)
    with pytest.raises(InvalidInputError) as refused:
        load_calibration(path)
    assert refused.value.field == f"--calibration {path}"
    assert refused.value.reason.startswith(said), refused.value.reason
    assert "Error(" not in str(refused.value) and "\n" not in str(refused.value)


def test_a_whole_float_size_and_an_absent_distortion_still_load(tmp_path: Path) -> None:
    values = {k: v for k, v in SHIPPED.items() if k != "distortion"}
    path = tmp_path / "cal.json"
    path.write_text(json.dumps({**values, "image_size": [640.0, 480.0]}))
    calibration = load_calibration(path)
    assert calibration.image_size == (640, 480) and calibration.distortion.shape == (0,)
    assert load_calibration(DEMO / "calibration.json").image_size == (640, 480)


def test_an_unknown_key_is_refused_by_name_not_dropped(tmp_path: Path) -> None:
    """A misspelt "distortion" would otherwise load as a lens without distortion."""
    values = {k: v for k, v in SHIPPED.items() if k != "distortion"}
    path = tmp_path / "cal.json"
    path.write_text(json.dumps({**values, "distorsion": SHIPPED["distortion"]}))
    with pytest.raises(InvalidInputError) as refused:
        load_calibration(path)
    assert refused.value.reason.startswith('unknown key "distorsion" (a calibration holds "K",')


def test_the_caller_names_the_file_it_is(tmp_path: Path) -> None:
    """``field`` replaces match's ``--calibration PATH``: ``FIELD: PATH: why``."""
    path = _written(tmp_path, K="abc")
    with pytest.raises(InvalidInputError) as refused:
        load_calibration(path, field="dataset")
    assert str(refused.value).startswith(f"dataset: {path}: K: expected a 3x3 list")
    with pytest.raises(InvalidInputError, match=f"^dataset: {tmp_path / 'none.json'}: no such"):
        load_calibration(tmp_path / "none.json", field="dataset")
    with pytest.raises(InvalidInputError, match=f"^--calibration {tmp_path}: is a directory"):
        load_calibration(tmp_path)


def test_match_names_the_calibration_key_on_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    path = _written(tmp_path, K="abc")
    argv = ["match", "--query", str(DEMO / "frame.jpg"), "--tile", str(DEMO / "tile_a.png")]
    assert main([*argv, "--calibration", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"c3-matcher: --calibration {path}: K: expected a 3x3 list of numbers "
        "([[a, b, c], [d, e, f], [g, h, i]]), got 'abc'"
    )
