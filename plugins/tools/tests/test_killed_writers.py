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


def test_a_store_another_build_finished_meanwhile_is_kept_not_replaced(tmp_path: Path) -> None:
    """Two builds of one store without --force: the second to finish is refused, naming the
    path, and the first one's store stays byte for byte; nothing is left beside it."""
    store = tmp_path / "tiles.mbtiles"
    second = MBTilesWriter(store)
    second.put_tile(1, 0, 0, b"the second build")
    with MBTilesWriter(store) as first:
        first.put_tile(1, 0, 0, b"the first build")
    kept = store.read_bytes()
    with pytest.raises(InvalidInputError, match="appeared while this build ran.*--force"):
        second.close()
    assert store.read_bytes() == kept
    assert [p.name for p in tmp_path.iterdir()] == ["tiles.mbtiles"]
    forced = MBTilesWriter(store, overwrite=True)
    forced.put_tile(1, 0, 0, b"forced")
    forced.close()
    assert store.read_bytes() != kept and [p.name for p in tmp_path.iterdir()] == ["tiles.mbtiles"]


def test_where_the_filesystem_has_no_hard_links_the_store_is_still_named(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_links(src: object, dst: object) -> None:
        raise OSError(1, "Operation not permitted")

    monkeypatch.setattr("os.link", no_links)
    store = tmp_path / "tiles.mbtiles"
    with MBTilesWriter(store) as w:
        w.put_tile(1, 0, 0, b"a whole store")
    assert [p.name for p in tmp_path.iterdir()] == ["tiles.mbtiles"]
    late = MBTilesWriter(tmp_path / "late.mbtiles")
    (tmp_path / "late.mbtiles").write_bytes(b"another build's")
    with pytest.raises(InvalidInputError, match="late.mbtiles exists"):
        late.close()
    assert (tmp_path / "late.mbtiles").read_bytes() == b"another build's"


def test_a_dataset_replacement_killed_between_its_renames_loses_nothing(tmp_path: Path) -> None:
    """Where the two directories cannot be swapped in one step, ``--force`` renames the old
    dataset aside before the new one takes its place. Killed between the two, only the hidden
    copy was left, and the next writer deleted it: now it is OUT again."""
    import subprocess
    import sys
    import textwrap

    out = tmp_path / "flight"
    out.mkdir()
    (out / "dataset.json").write_text('{"old": 1}')
    script = f"""
        import os, signal
        from pathlib import Path
        import c3_matcher.atomic
        from c3_matcher_tools.dataset.atomic import atomic_directory

        c3_matcher.atomic._exchange = lambda a, b: False  # a system that cannot swap
        rename = Path.rename

        def killed_after_aside(self, target):
            done = rename(self, target)
            if str(target).endswith(".aside"):
                os.kill(os.getpid(), signal.SIGKILL)
            return done

        Path.rename = killed_after_aside
        with atomic_directory(Path({str(out)!r}), force=True) as tmp:
            (tmp / "dataset.json").write_text('{{"new": 1}}')
        """
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(script)], capture_output=True)
    assert done.returncode == -9, done.stderr
    assert not out.exists() and any(p.name.endswith(".aside") for p in tmp_path.iterdir())
    with pytest.raises(InvalidInputError, match="already exists"), atomic_directory(out):
        pass
    assert (out / "dataset.json").read_text() == '{"old": 1}'
    with atomic_directory(out, force=True) as tmp:
        (tmp / "dataset.json").write_text('{"new": 2}')
    assert [p.name for p in tmp_path.iterdir()] == ["flight"]
    assert (out / "dataset.json").read_text() == '{"new": 2}'


def test_a_forced_dataset_replacement_swaps_the_two_in_one_step(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On Linux OUT is never missing while it is replaced: the old and new are swapped."""
    import c3_matcher.atomic

    out = tmp_path / "flight"
    out.mkdir()
    (out / "dataset.json").write_text('{"old": 1}')
    swaps: list[bool] = []
    exchange = c3_matcher.atomic._exchange

    def seen(a: Path, b: Path) -> bool:
        swaps.append(exchange(a, b))
        return swaps[-1]

    monkeypatch.setattr(c3_matcher.atomic, "_exchange", seen)
    with atomic_directory(out, force=True) as tmp:
        (tmp / "dataset.json").write_text('{"new": 1}')
    assert swaps == [True]
    assert [p.name for p in tmp_path.iterdir()] == ["flight"]
    assert (out / "dataset.json").read_text() == '{"new": 1}'


def test_two_forced_builds_of_one_store_the_later_to_finish_is_refused(tmp_path: Path) -> None:
    """Two ``tiles build --force`` of one store at once: each would say it wrote the store,
    while it holds one build's tiles. The first to finish replaces it; the second is refused,
    naming the path, and the first one's store stays byte for byte, nothing beside it."""
    store = tmp_path / "tiles.mbtiles"
    with MBTilesWriter(store) as old:
        old.put_tile(1, 0, 0, b"the store before")
    second = MBTilesWriter(store, overwrite=True)
    second.put_tile(1, 0, 0, b"the second build")
    with MBTilesWriter(store, overwrite=True) as first:
        first.put_tile(1, 0, 0, b"the first build")
    kept = store.read_bytes()
    with pytest.raises(InvalidInputError, match="was replaced while this build ran"):
        second.close()
    assert store.read_bytes() == kept
    assert [p.name for p in tmp_path.iterdir()] == ["tiles.mbtiles"]
