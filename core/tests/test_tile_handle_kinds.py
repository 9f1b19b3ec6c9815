"""A tile file handle refuses at construction what it could never read: a directory, and a
named pipe (reading one would block the frame until a writer came)."""

from __future__ import annotations

import os

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.tiles import MmapTileHandle


def test_a_directory_is_refused_naming_it(tmp_path):
    folder = tmp_path / "tiles.png"
    folder.mkdir()
    with pytest.raises(InvalidInputError, match=r"tiles\.png.*it is a directory"):
        MmapTileHandle(folder)


def test_a_named_pipe_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "tile.png"
    os.mkfifo(fifo)
    with pytest.raises(
        InvalidInputError, match=r"tile\.png: cannot read image file: it is a FIFO$"
    ):
        MmapTileHandle(fifo)
