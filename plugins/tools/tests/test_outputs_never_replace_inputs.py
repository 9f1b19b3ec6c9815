"""Every command that writes with ``--force`` refuses an OUT that is, or is a folder above, one of
its inputs (paths resolved, links followed): exit 2, one line naming both, the inputs untouched.
The refusal comes before any input is read, so the inputs here are placeholders."""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher.atomic import refuse_output_over_inputs
from c3_matcher.cli import main
from c3_matcher.errors import InvalidInputError

INPUTS = ("images/IMG_0000.jpg", "tele.csv", "flight.ulg", "calib.json", "tiles.mbtiles", "o.tif")


def _inputs(folder: Path) -> dict[Path, bytes]:
    """Placeholder input files under ``folder``, by path, with their bytes."""
    files = {folder / name: f"input {name}".encode() for name in INPUTS}
    for path, data in files.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    return files


@pytest.mark.parametrize(
    "argv",
    [
        ["dataset", "import", "images", "tele.csv", "calib.json", "tiles.mbtiles"],
        ["dataset", "import", "images", "flight.ulg", "calib.json", "tiles.mbtiles"],
        ["dataset", "render", "o.tif", "tiles.mbtiles"],
    ],
    ids=["import-csv", "import-ulog", "render"],
)
def test_a_dataset_out_holding_its_inputs_is_refused_with_force(
    argv: list[str],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    files = _inputs(tmp_path)
    monkeypatch.chdir(tmp_path)
    assert main([*argv, str(tmp_path), "--force"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    assert f"{tmp_path} holds the input {argv[2]}" in err, err
    assert {p: p.read_bytes() for p in files} == files


def test_tiles_build_onto_its_own_geotiff_is_refused_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    files = _inputs(tmp_path)
    geotiff = str(tmp_path / "o.tif")
    assert main(["tiles", "build", geotiff, geotiff, "--force"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"OUT: {geotiff} is the input {geotiff}" in err, err
    assert {p: p.read_bytes() for p in files} == files


def test_tiles_build_into_a_name_ending_in_a_slash_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``tiles build o.tif newtiles/`` meant a folder: it wrote an MBTiles file called
    ``newtiles``. OUT is the store file; the refusal says so, with a name to use."""
    _inputs(tmp_path)
    out = f"{tmp_path / 'newtiles'}/"
    with pytest.raises(SystemExit) as stop:
        main(["tiles", "build", str(tmp_path / "o.tif"), out])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"{out} names a folder: OUT is the .mbtiles file to write" in err, err
    assert not (tmp_path / "newtiles").exists()


def test_inputs_are_compared_resolved_through_links(tmp_path: Path) -> None:
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "tele.csv").write_text("t")
    (tmp_path / "link").symlink_to(tmp_path / "data")
    with pytest.raises(InvalidInputError, match="holds the input"):
        refuse_output_over_inputs(tmp_path / "link", [tmp_path / "data" / "tele.csv"])
    with pytest.raises(InvalidInputError, match="is the input"):
        refuse_output_over_inputs(tmp_path / "data" / ".." / "data", [tmp_path / "link"])


def test_an_out_beside_or_inside_the_inputs_and_absent_inputs_pass(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    inputs = [tmp_path / "images", tmp_path / "tele.csv", None, "-"]
    refuse_output_over_inputs(tmp_path / "flight", inputs)  # a sibling
    refuse_output_over_inputs(tmp_path / "images" / "flight", inputs)  # inside: nothing lost
    refuse_output_over_inputs(tmp_path / "-" / "x", inputs)  # '-' stands for no file
