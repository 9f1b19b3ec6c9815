"""A dataset's name is UTF-8 text (JSON text in ``dataset.json``, drawn in its charts): an
import into an OUT whose name holds a byte that is no UTF-8 is refused as bad input naming OUT,
before anything is written, unless ``--name`` gives it one; such a ``--name``, and a
``dataset.json`` naming its dataset so, are refused too. An OUT 250 bytes long is written."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher_tools.dataset.format import load_dataset

from .conftest import C3, DEMO, SmallFlight


def _inputs(root: Path) -> list[Path]:
    """IMAGES TELEMETRY CALIBRATION STORE of a one-frame flight."""
    images = root / "images"
    images.mkdir()
    frame = json.loads((DEMO / "frames.jsonl").read_text().splitlines()[0])
    shutil.copyfile(DEMO / frame["image"], images / "a.jpg")
    pose, (roll, pitch, yaw) = frame["pose"], frame["attitude_deg"]
    (root / "t.csv").write_text(
        "time_s,image,lat,lon,altitude_m,roll_deg,pitch_deg,yaw_deg\n"
        f"0,a.jpg,{pose['nadir_lat']},{pose['nadir_lon']},{frame['height_m']},"
        f"{roll},{pitch},{yaw}\n"
    )
    return [images, root / "t.csv", DEMO / "calibration.json", DEMO / "tiles.mbtiles"]


def test_an_out_named_in_bytes_is_refused_naming_out(tmp_path: Path, c3: C3) -> None:
    done = c3("dataset", "import", *_inputs(tmp_path), tmp_path / "ds\udce9")
    assert done.returncode == 2, done.stderr
    assert "c3-matcher: OUT: " in done.stderr and "not UTF-8" in done.stderr, done.stderr
    assert "--name" in done.stderr
    assert not (tmp_path / "ds\udce9").exists()


def test_an_out_named_in_bytes_takes_the_name_given(tmp_path: Path, c3: C3) -> None:
    out = tmp_path / "ds\udce9"
    done = c3("dataset", "import", *_inputs(tmp_path), out, "--name", "flight é", "--json")
    assert done.returncode == 0, done.stderr
    assert load_dataset(out).name == "flight é"


def test_a_name_given_in_bytes_is_refused(tmp_path: Path, c3: C3) -> None:
    done = c3("dataset", "import", *_inputs(tmp_path), tmp_path / "ds", "--name", "x\udce9")
    assert done.returncode == 2, done.stderr
    assert "--name" in done.stderr and "not UTF-8" in done.stderr, done.stderr


def test_a_dataset_named_by_a_lone_surrogate_is_refused(small_flight: SmallFlight) -> None:
    flight = small_flight("vol\udce9")
    with pytest.raises(InvalidInputError) as refused:
        load_dataset(flight)
    assert "name: 'vol\\udce9': is not UTF-8 text" in refused.value.reason, refused.value.reason


def test_an_out_250_bytes_long_is_written(tmp_path: Path, c3: C3) -> None:
    out = tmp_path / ("d" * 250)
    done = c3("dataset", "import", *_inputs(tmp_path), out)
    assert done.returncode == 0, done.stderr
    assert load_dataset(out).name == out.name
