"""A tile store or dataset writer killed outright (out of memory, SIGKILL, power cut) leaves
its unfinished work beside the output; the next writer of that output removes it, and the
output itself is never half written."""

from __future__ import annotations

from pathlib import Path

import pytest

from c3_matcher.errors import InvalidInputError
from c3_matcher.testing.killed import killed_while_writing
from c3_matcher_tools.dataset.atomic import atomic_directory
from c3_matcher_tools.tilestore.writer import MBTilesWriter


def test_a_killed_tile_store_build_leaves_nothing_after_the_next(tmp_path: Path) -> None:
    store = tmp_path / "tiles.mbtiles"
    killed_while_writing(
        f"""
        from c3_matcher_tools.tilestore.writer import MBTilesWriter
        with MBTilesWriter({str(store)!r}) as w:
            w.put_tile(1, 0, 0, b"half a store")
        """
    )
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left and all(name.startswith(".tiles.mbtiles.tmp-") for name in left)
    assert not store.exists()
    with MBTilesWriter(store) as w:
        w.put_tile(1, 0, 0, b"a whole store")
    assert [p.name for p in tmp_path.iterdir()] == ["tiles.mbtiles"]


def test_a_killed_dataset_write_leaves_nothing_after_the_next(tmp_path: Path) -> None:
    out = tmp_path / "flight"
    killed_while_writing(
        f"""
        from pathlib import Path
        from c3_matcher_tools.dataset.atomic import atomic_directory
        with atomic_directory(Path({str(out)!r})) as tmp:
            (tmp / "frames").mkdir()
        """
    )
    (left,) = tmp_path.iterdir()
    assert left.name.startswith(".flight.tmp-") and (left / "frames").is_dir()
    with atomic_directory(out) as tmp:
        (tmp / "dataset.json").write_text("{}")
    assert [p.name for p in tmp_path.iterdir()] == ["flight"]
    assert [p.name for p in out.iterdir()] == ["dataset.json"]


def test_an_out_that_cannot_be_made_is_named_not_its_temporary_folder() -> None:
    """/proc takes no new folder: the refusal names OUT, never the hidden name beside it."""
    with pytest.raises(InvalidInputError) as refused, atomic_directory(Path("/proc/c3-out")):
        pass
    assert str(refused.value).startswith("OUT: /proc/c3-out: cannot be written (")
    assert ".tmp-" not in str(refused.value)
