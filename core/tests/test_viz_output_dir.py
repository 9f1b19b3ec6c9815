"""A picture whose folder is a file says that file is not a directory, as every command's
output does (it said "[Errno 17] File exists"); ``match`` still prints its result and exits 2,
for ``--viz`` and ``--fdr`` alike."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from c3_matcher.viz import write_png

from .demo_match import DEMO_MATCH


@pytest.mark.parametrize("under", ["v.png", "deeper/v.png"])
def test_a_picture_under_a_file_says_that_file_is_not_a_directory(
    tmp_path: Path, under: str
) -> None:
    afile = tmp_path / "afile"
    afile.write_text("{}\n")
    with pytest.raises(NotADirectoryError) as refused:
        write_png(np.zeros((8, 8, 3), np.uint8), afile / under)
    assert str(refused.value) == f"{afile} is not a directory"
    assert afile.read_text() == "{}\n" and sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_a_picture_in_new_folders_is_written(tmp_path: Path) -> None:
    out = write_png(np.zeros((8, 8, 3), np.uint8), tmp_path / "a" / "b" / "v.png")
    assert out.read_bytes().startswith(b"\x89PNG")


def test_match_says_which_file_is_not_a_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import os

    from c3_matcher.cli import main

    for key in [k for k in os.environ if k.upper().startswith("C3_MATCHER_")]:
        monkeypatch.delenv(key)
    monkeypatch.chdir(tmp_path)
    Path("afile").write_text("{}\n")
    assert main([*DEMO_MATCH, "--fdr", "afile/f.jsonl", "--viz", "afile/v.png"]) == 2
    captured = capsys.readouterr()
    assert json.loads(captured.out)["per_candidate"]  # the result was printed
    said = [line for line in captured.err.splitlines() if line.startswith("c3-matcher: ")]
    assert said == [
        "c3-matcher: fdr.path afile/f.jsonl: afile is not a directory; the result was printed "
        "but NOT recorded in the FDR",
        "c3-matcher: --viz afile/v.png: cannot write the picture: afile is not a directory",
    ]
