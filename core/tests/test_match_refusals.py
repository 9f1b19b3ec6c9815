"""``c3-matcher match`` refuses to write its outputs over its inputs: an ``--fdr`` (or ``[fdr]
path``) or ``--viz`` naming the ``--query``, a ``--tile``, the ``--calibration`` or each other
(a hard link included) is bad input (exit 2, one line naming the option and the input), and the
file is left byte for byte as it was (the recorder used to cut a tile's tail as a "torn line"
and append its records to the image)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "data" / "demo"


@pytest.fixture
def inputs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, Path]:
    """Copies of the demo query, tile and calibration, and a clean environment."""
    import os

    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)
    files = {
        "query": tmp_path / "frame.jpg",
        "tile": tmp_path / "tile_a.png",
        "calibration": tmp_path / "calibration.json",
    }
    for name, source in (
        ("frame.jpg", "query"),
        ("tile_a.png", "tile"),
        ("calibration.json", "calibration"),
    ):
        shutil.copy(DEMO / name, files[source])
    monkeypatch.setenv("C3_MATCHER_FDR__PATH", str(tmp_path / "fdr.jsonl"))
    return files


@pytest.mark.parametrize(
    ("extra", "victim", "needles"),
    [
        (["--fdr", "{tile}"], "tile", ["--fdr", "is the input"]),
        (["--fdr", "{query}"], "query", ["--fdr", "is the input"]),
        (["--fdr", "{calibration}"], "calibration", ["--fdr", "is the input"]),
        (["--viz", "{tile}"], "tile", ["--viz", "is the input"]),
        (["--viz", "{query}"], "query", ["--viz", "is the input"]),
        (["--viz", "{fdr}"], "fdr", ["--viz", "is the input"]),
    ],
)
def test_match_refuses_to_write_an_output_over_an_input(
    inputs: dict[str, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    victim: str,
    needles: list[str],
) -> None:
    from c3_matcher.cli import main

    files = {**inputs, "fdr": tmp_path / "fdr.jsonl"}
    files["fdr"].write_bytes(b'{"kind": "earlier record"}\n')
    before = {name: path.read_bytes() for name, path in files.items()}
    argv = [
        "match",
        "--query",
        str(files["query"]),
        "--tile",
        str(files["tile"]),
        "--calibration",
        str(files["calibration"]),
        *(arg.format(**{k: str(v) for k, v in files.items()}) for arg in extra),
    ]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "internal error" not in err
    assert all(needle in err for needle in needles), err
    assert str(files[victim]) in err
    assert {name: path.read_bytes() for name, path in files.items()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in files.values())


@pytest.mark.parametrize("option", ["--fdr", "--viz"])
def test_an_output_that_is_a_directory_is_said_to_be_one(
    inputs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str], option: str
) -> None:
    """The folder holding the inputs is refused as a folder, not as a replacement of them."""
    from c3_matcher.cli import main

    argv = ["match", "--query", str(inputs["query"]), "--tile", str(inputs["tile"])]
    assert main([*argv, option, str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == f"c3-matcher: {option}: {tmp_path} is a directory: it names a file to write"


def test_the_configured_fdr_path_may_not_be_an_input_either(
    inputs: dict[str, Path], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    tile = inputs["tile"]
    before = tile.read_bytes()
    monkeypatch.setenv("C3_MATCHER_FDR__PATH", str(tile.parent / "." / tile.name))
    assert main(["match", "--query", str(inputs["query"]), "--tile", str(tile)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "[fdr] path" in err and f"is the input {tile}" in err
    assert tile.read_bytes() == before
    assert not tile.with_name(tile.name + ".torn").exists()


def test_a_hard_link_to_an_input_is_that_input(
    inputs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    from c3_matcher.cli import main

    tile = inputs["tile"]
    before = tile.read_bytes()
    alias = tile.with_name("alias.png")
    alias.hardlink_to(tile)
    argv = ["match", "--query", str(inputs["query"]), "--tile", str(tile), "--viz", str(alias)]
    assert main(argv) == 2
    assert f"is the input {tile}" in capsys.readouterr().err
    assert tile.read_bytes() == before


@pytest.mark.parametrize("name", ["match.jpg", "match", "match.png.webp"])
def test_a_picture_not_named_png_is_refused_before_matching(
    inputs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str
) -> None:
    """The picture is PNG data: under a .jpg name strict viewers and upload tools reject it."""
    from c3_matcher.cli import main

    argv = ["match", "--query", str(inputs["query"]), "--tile", str(inputs["tile"])]
    assert main([*argv, "--viz", str(tmp_path / name)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == f"c3-matcher: --viz: {tmp_path / name}: the picture is a PNG; name it *.png"
    assert not (tmp_path / name).exists() and not (tmp_path / "fdr.jsonl").exists()
