"""A dataset is never replaced under a run that reads it: ``replay``, ``eval`` and ``bench
--data`` hold it (``flock`` shared on its directory) from the first read to the end, and
``dataset render`` or ``import --force`` holds it alone from its check to the swap: the second
to come is refused, naming the other, and the dataset is left as it was (two real processes)."""

from __future__ import annotations

import fcntl
import os
import subprocess
import sys
import textwrap
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from c3_matcher.cli import main

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
REPO = Path(__file__).resolve().parents[3]
FLIGHT = REPO / "data" / "flights" / "naip_demo"
NAIP_2020 = REPO / "data" / "imagery" / "naip_timeseries" / "m_4709963_se_14_1_20200831.tif"


@contextmanager
def _held_by_another_process(directory: Path, how: str) -> Iterator[int]:
    """``directory`` locked (``LOCK_SH`` or ``LOCK_EX``) by a second process, as a run or a
    replacing writer holds it; its process id."""
    script = f"""
        import fcntl, os, sys, time
        fd = os.open({str(directory)!r}, os.O_RDONLY | os.O_DIRECTORY)
        fcntl.flock(fd, fcntl.{how})
        print("held", flush=True)
        time.sleep(120)
        """
    proc = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(script)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline() == "held\n"
        yield proc.pid
    finally:
        proc.kill()
        proc.wait()


def _listing(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def test_force_is_refused_while_a_run_reads_the_dataset(
    small_flight: SmallFlight, capsys: pytest.CaptureFixture[str]
) -> None:
    dataset = small_flight("small")
    before = _listing(dataset)
    argv = ["dataset", "render", str(NAIP_2020), str(FLIGHT / "tiles.mbtiles"), str(dataset)]
    with _held_by_another_process(dataset, "LOCK_SH") as pid:
        assert main([*argv, "--frames", "3", "--force"]) == 2
    said = capsys.readouterr().err
    assert f"OUT: {dataset}: a run is reading this dataset (process {pid}: " in said, said
    assert "wait for it to finish, or choose another OUT" in said
    assert _listing(dataset) == before


def test_a_run_is_refused_while_its_dataset_is_being_replaced(
    small_flight: SmallFlight, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    dataset = small_flight("small")
    bench = ["bench", "--data", str(dataset), "--runs", "1", "--no-reference"]
    for command in ("replay", "eval", "bench"):
        out = tmp_path / command
        args = [command, str(dataset), "--strategy", "sift_magsac", "--out", str(out)]
        args = [*bench, "--strategy", "sift_magsac"] if command == "bench" else args
        with _held_by_another_process(dataset, "LOCK_EX") as pid:
            assert main(args) == 2
        said = capsys.readouterr().err
        assert f"dataset: {dataset}: another process is replacing this dataset (process {pid}" in (
            said
        ), said
        assert not out.exists()


def test_runs_of_one_dataset_read_it_together(small_flight: SmallFlight) -> None:
    """Shared: a second reader (another replay, an eval) is not refused by the first."""
    from c3_matcher_tools.dataset.lock import reading_dataset

    dataset = small_flight("small")
    with _held_by_another_process(dataset, "LOCK_SH"), reading_dataset(dataset):
        fd = os.open(dataset, os.O_RDONLY | os.O_DIRECTORY)
        try:  # a replacing writer is shut out while both read
            with pytest.raises(BlockingIOError):
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        finally:
            os.close(fd)
