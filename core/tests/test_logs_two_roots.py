"""Two composed roots alive in one process (two cameras, or a root composed before the old one
is closed), over the same helpers, with the real engines on the demo frame: each matcher record
reaches stderr once, each root's FDR holds the log records of its own frames only, a record
logged outside any root's work goes to the earliest root still open, and closing either root
leaves the other's logging as it was. Run in a fresh process: the real stderr, nothing left
over from other tests' sinks."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from c3_matcher.fdr import read_fdr

DEMO = Path(__file__).resolve().parents[2] / "data" / "demo"

PROGRAM = textwrap.dedent(
    """
    import dataclasses, sys, threading, uuid
    from pathlib import Path
    from c3_matcher import InsufficientInliersError, RerankResult
    from c3_matcher.compose import build_default_helpers, compose_root
    from c3_matcher.config import C3Settings
    from c3_matcher.logs import log_event
    from c3_matcher.demo import demo_inputs

    engines, out, demo, first = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]), sys.argv[4]

    def settings(name):
        return C3Settings(engines={"directory": engines}, fdr={"path": out / f"{name}.jsonl"})

    def refused(root, frame_id):  # a frame of this root's with no candidate: its ERROR
        frame = dataclasses.replace(demo_frame, frame_id=uuid.UUID(int=frame_id))
        try:
            root.matcher.match(frame, RerankResult(frame.frame_id, ()), calibration)
        except InsufficientInliersError:
            return
        raise AssertionError("matched a frame without candidates")

    demo_frame, rerank, calibration = demo_inputs(demo)
    helpers = build_default_helpers(settings("a"))  # shared by both roots
    roots = {"a": compose_root(settings("a"), helpers), "b": compose_root(settings("b"), helpers)}
    result = roots["a"].matcher.match(demo_frame, rerank, calibration)  # a real fix (frame 1)
    assert result.per_candidate[0].inlier_count >= 60
    refused(roots["a"], 11)
    refused(roots["b"], 21)
    log_event("WARNING", "c3.test.unrooted", "outside any root's work")
    thread = threading.Thread(
        target=log_event, args=("WARNING", "c3.test.thread", "a thread of the program's")
    )
    thread.start()
    thread.join()
    roots[first].close()
    survivor = roots["b" if first == "a" else "a"]
    refused(survivor, 31 if survivor is roots["a"] else 32)
    log_event("WARNING", "c3.test.after_close", "outside any root's work, one root left")
    survivor.close()
    """
)


def _log_forwards(path: Path) -> list[dict[str, Any]]:
    """The log records a root's FDR holds (``log.error``, ``log.warning``), their payloads."""
    return [r["payload"] for r in read_fdr(path) if r["kind"].startswith("log.")]


def _frames(forwards: list[dict[str, Any]]) -> set[int]:
    return {int(f["frame_id"].replace("-", ""), 16) for f in forwards if "frame_id" in f}


@pytest.mark.parametrize("first", ["a", "b"])
def test_two_roots_each_record_once_each_fdr_its_own_and_one_left_after_a_close(
    engine_dir: Path, tmp_path: Path, first: str
) -> None:
    proc = subprocess.run(
        [sys.executable, "-c", PROGRAM, str(engine_dir), str(tmp_path), str(DEMO), first],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.startswith("{")]
    assert [line for line, n in Counter(lines).items() if n > 1] == []  # no line said twice
    kinds = Counter(json.loads(line)["kind"] for line in lines)
    # composed twice over the same helpers: each root's start-up said once, by its own sink
    assert kinds["c3.inference.provider_selected"] == 2 and kinds["c3.matcher.ready"] == 2
    assert kinds["c3.matcher.insufficient_inliers"] == 3  # frames 11, 21 and the survivor's
    for unrooted in ("c3.test.unrooted", "c3.test.thread", "c3.test.after_close"):
        assert kinds[unrooted] == 1, unrooted  # outside any root: still said, once

    survivor = "b" if first == "a" else "a"
    a, b = (_log_forwards(tmp_path / f"{name}.jsonl") for name in "ab")
    assert _frames(a) == ({11, 31} if survivor == "a" else {11})  # its own frames' ERRORs only
    assert _frames(b) == ({21, 32} if survivor == "b" else {21})
    # both open: the earliest root (a) takes what no root logged; then the one left does
    assert [f["kind"] for f in a if f["kind"].startswith("c3.test.")] == [
        "c3.test.unrooted",
        "c3.test.thread",
        *(["c3.test.after_close"] if survivor == "a" else []),
    ]
    assert [f["kind"] for f in b if f["kind"].startswith("c3.test.")] == (
        ["c3.test.after_close"] if survivor == "b" else []
    )
