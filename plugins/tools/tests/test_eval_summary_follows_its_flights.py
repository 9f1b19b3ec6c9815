"""The ``summary.json`` of an eval over several flights says what the folders beside it hold: a
later eval of one of those flights into its folder replaces that flight's rows with its own
(said on stderr), one that writes another flight into a flight's folder removes the summary,
and one into a folder the summary does not name leaves it as it is. Two-frame cuts of the demo
flight through the ``sift_magsac`` baseline."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

SmallFlight = Callable[..., Path]  # the fixtures of conftest.py
C3 = Callable[..., subprocess.CompletedProcess[str]]
QUICK = ("--strategy", "sift_magsac", "--no-baseline", "--determinism-frames", "1")
QUICK += ("--samples", "0")


def _rows(root: Path) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = json.loads((root / "summary.json").read_text())
    return rows


def _one_frame(flight: Path) -> None:
    """``flight`` cut to its first frame: the same name, other figures."""
    first = (flight / "frames.jsonl").read_text().splitlines()[0]
    (flight / "frames.jsonl").write_text(first + "\n")


def test_a_later_eval_of_one_flight_refreshes_its_rows_of_the_summary(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    north, south = (small_flight(name, where=name) for name in ("north", "south"))
    root = tmp_path / "out"
    both = c3("eval", str(north), str(south), *QUICK, "--out", str(root))
    assert both.returncode == 0, both.stderr[-2000:]
    before = _rows(root)
    assert [r["flight"] for r in before] == ["north", "south"]
    assert before[0]["candidates"] > 0

    _one_frame(north)
    single = c3("eval", str(north), *QUICK, "--out", str(root / "north"))
    assert single.returncode == 0, single.stderr[-2000:]
    (entry,) = json.loads((root / "north" / "eval.json").read_text())["strategies"]
    after = _rows(root)
    assert [r["flight"] for r in after] == ["north", "south"]
    assert after[0]["candidates"] == entry["timing"]["candidates"] < before[0]["candidates"]
    assert after[1] == before[1]  # south's folder is as that run left it
    assert f"{root.resolve() / 'summary.json'}: north's rows replaced by this run's" in (
        single.stderr
    )

    west = small_flight("west", where="west")  # a folder the summary does not name
    beside = c3("eval", str(west), *QUICK, "--out", str(root / "west"))
    assert beside.returncode == 0, beside.stderr[-2000:]
    assert _rows(root) == after and "summary.json" not in beside.stderr


def test_another_flight_in_a_flights_folder_removes_the_summary(
    small_flight: SmallFlight, c3: C3, tmp_path: Path
) -> None:
    north, south = (small_flight(name, where=name) for name in ("north", "south"))
    work = tmp_path / "work"
    work.mkdir()
    both = c3("eval", str(north), str(south), *QUICK, cwd=work)  # the default root, out/eval
    assert both.returncode == 0, both.stderr[-2000:]
    root = work / "out" / "eval"
    assert (root / "summary.json").is_file()
    swapped = c3("eval", str(north), *QUICK, "--out", str(root / "south"))
    assert swapped.returncode == 0, swapped.stderr[-2000:]
    assert not (root / "summary.json").exists()
    said = f"{root.resolve() / 'summary.json'} removed: south's folder beside it now holds north's"
    assert said in swapped.stderr, swapped.stderr[-2000:]
    again = c3("eval", str(north), str(south), *QUICK, cwd=work)  # a summary again
    assert again.returncode == 0, again.stderr[-2000:]
    assert [r["flight"] for r in _rows(root)] == ["north", "south"]
